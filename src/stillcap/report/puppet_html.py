"""The HTML report of a puppet result (``report.html``, :func:`write_html`), in the style of the
pitch and hand reports: the notes, the comparison with the truth (studio captures), the 3D plots,
the markers with the views they rest on and their errors, the pose's joint angles, the views and
their overlays.

The images are linked by their paths relative to the report (``markers_3d.png``,
``skeleton_3d.png``, ``overlays/*.png``): they are written beside it by
:func:`stillcap.report.puppet.write_report`, and the folder is the report.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from stillcap.files.atomic import write_text
from stillcap.report.pitch import _CSS, _fmt, _table

__all__ = ["comparison_rows", "puppet_notes", "report_html", "write_html"]

_CSS_MORE = ".views{display:flex;flex-wrap:wrap;gap:8px}.views figure{margin:0;width:32%}" \
            ".views figcaption{font-size:12px;color:#555}"


def comparison_rows(cmp) -> list[tuple[str, str]]:
    """``(quantity, value)`` rows of a :class:`~stillcap.studio.compare.puppet.PuppetComparison`
    (the CLI's table and the report's).

    Identification counts are over (view, bead) pairs with two denominators, each named: the
    beads whose centre the truth shows (for "right") and every identification made (for "wrong":
    partly hidden beads, whose centre is hidden, are identified too).
    """
    rows = [("beads identified right, % of the beads whose centre a view shows (per view and bead)",
             f"{cmp.right_pct:.1f} %  ({cmp.right_visible} of {cmp.visible})"),
            ("identifications wrong, % of all identifications (per view and bead, partly hidden beads too)",
             f"{cmp.wrong_pct:.2f} %  ({cmp.wrong} of {cmp.identified}; used in 3D: {cmp.wrong_used})"),
            ("markers seen in 2+ views, recovered", f"{cmp.recovered_seen_twice} of {cmp.seen_twice}"),
            ("3D marker error RMS / max", f"{cmp.marker_rms_mm():.3f} / {cmp.marker_max_mm():.3f} mm")]
    for g in cmp.bone_groups:
        rms, mx = cmp.bone_stats(g)
        trms, tmx = cmp.bone_stats(g, thesis=True)
        rows.append((f"bone direction, {g} ({', '.join(cmp.bone_groups[g])})",
                     f"{rms:.2f} / {mx:.2f} deg (thesis {trms:.2f} / {tmx:.2f})"))
    rms, mx = cmp.joint_stats()
    trms, tmx = cmp.joint_stats(thesis=True)
    rows.append(("joint position, all joints", f"{rms:.2f} / {mx:.2f} mm (thesis {trms:.2f} / {tmx:.2f})"))
    for g in cmp.joint_groups:
        rms, mx = cmp.joint_stats(g)
        rows.append((f"joint position, {g}", f"{rms:.2f} / {mx:.2f} mm"))
    return rows


def puppet_notes(result) -> list[str]:
    """What a reader should know about a result: missing and weakly seen markers, views left
    out, a pose fit that did not converge."""
    m = result.markers
    notes = []
    if m.missing:
        notes.append(f"seen in fewer than two views (no 3D position): {', '.join(m.missing)}")
    weak = [n for n, ok, w in zip(m.names, m.ok, m.whole_views) if ok and w < 2]
    if weak:
        notes.append("fewer than two views show the whole bead (partly hidden or at the image border), the 3D "
                     f"position may be off by a few tenths of a mm: {', '.join(weak)}")
    partial, outlier = int(m.partial.sum()), int(m.outlier.sum())
    if partial or outlier:
        notes.append(f"observations left out: {partial} partly hidden beads, {outlier} disagreeing views (outliers)")
    if not result.fit.success:
        notes.append("the pose fit did not converge")
    return notes


def _mm(v, digits: int = 2) -> str:
    return _fmt(float(v) * 1e3, digits)


def _marker_rows(result) -> tuple[list[str], list[list[str]]]:
    m, cmp = result.markers, result.comparison
    header = ["marker", "x mm", "y mm", "z mm", "views used", "whole views", "identified in", "reproj px",
              "fit residual mm"] + (["error mm"] if cmp is not None else []) + ["status"]
    rows = []
    for k, name in enumerate(m.names):
        ok = bool(m.ok[k])
        status = "missing: fewer than 2 views" if not ok else (
            "fewer than 2 whole views" if m.whole_views[k] < 2 else "")
        row = [name, *((_mm(v) for v in m.points[k]) if ok else ("", "", "")), str(int(m.n_views[k])),
               str(int(m.whole_views[k])), str(int(m.identified_views[k])), _fmt(m.reproj_error_px[k], 2),
               _mm(result.fit.residuals_m[k], 3)]
        if cmp is not None:
            row.append(_mm(cmp.marker_errors_m[k], 3))
        rows.append(row + [status])
    return header, rows


def _joint_rows(result) -> tuple[list[str], list[list[str]]]:
    pose, cmp = result.pose, result.comparison
    sk = pose.skeleton
    ang = sk.limit_angles_deg(pose.local_rotations)
    lim = sk.limits_deg
    fit_e = {} if cmp is None else cmp.bone_errors_deg
    header = ["joint", "parent", "X deg", "Y deg", "Z deg", "limits X / Y / Z deg", "x mm", "y mm", "z mm"]
    header += ["bone direction error deg", "joint position error mm"] if cmp is not None else []
    rows = []
    for j, name in enumerate(sk.names):
        p = sk.parents[j]
        limits = " / ".join(f"{lo:g}..{hi:g}" for lo, hi in lim[j])
        row = [name, sk.names[p] if p >= 0 else "(root)", *(_fmt(a, 1) for a in ang[j]), limits,
               *(_mm(v, 1) for v in pose.positions[j])]
        if cmp is not None:
            row += [_fmt(fit_e.get(name), 2), _mm(cmp.joint_errors_m[j], 2)]
        rows.append(row)
    return header, rows


def _view_rows(result) -> tuple[list[str], list[list[str]]]:
    m = result.markers
    header = ["view", "turn deg", "photo", "bead candidates", "identified", "used", "partly hidden", "outliers"]
    rows = []
    for v, name in enumerate(result.view_names):
        a = result.angles_deg[v]
        rows.append([str(name), "" if a is None else f"{a:g}", str((result.files or [""] * (v + 1))[v] or ""),
                     str(len(result.views[v].circles)) if result.views and result.views[v] is not None else "",
                     str(int(np.isfinite(m.observations[v, :, 0]).sum())), str(int(m.used[v].sum())),
                     str(int(m.partial[v].sum())), str(int(m.outlier[v].sum()))])
    return header, rows


def _img(rel: str, alt: str) -> str:
    return f"<img src='{html.escape(rel)}' alt='{html.escape(alt)}'>"


def report_html(result, folder, files) -> str:
    """The report as one HTML string; ``files`` are the images written into ``folder``, linked
    by their paths relative to it."""
    folder = Path(folder)
    rel = {Path(f).name: Path(f).resolve().relative_to(folder.resolve()).as_posix() for f in files}
    overlays = [Path(f) for f in files if Path(f).parent.name == "overlays"]
    m, fit, cmp = result.markers, result.fit, result.comparison
    src = result.source or {}
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>stillcap puppet report</title>"
             f"<style>{_CSS}{_CSS_MORE}</style></head><body>", "<h1>Puppet report</h1>",
             f"<p class='small'>{html.escape(str(src.get('type', 'photos')))}: {html.escape(str(src.get('path', '')))}"
             f"; marker set {html.escape(result.markerset.name)}; detector {html.escape(result.options.detector)}, "
             f"identification {html.escape(result.options.identify)}, pose {html.escape(result.options.pose)}. "
             f"Puppet frame (y up), positions in mm. See docs/puppet.md.</p>",
             f"<p>{int(m.ok.sum())} of {len(m.names)} markers in 3D from {len(result.rig)} views; pose fitted to "
             f"{fit.n_markers} markers with RMS {_mm(fit.rms_m, 3)} mm (the thesis's bone directions: "
             f"{_mm(np.sqrt(np.nanmean(fit.thesis_residuals_m ** 2)), 2)} mm).</p>"]
    notes = puppet_notes(result)
    if notes:
        parts.append("<h2 id='notes'>Notes</h2>")
        parts += [f"<div class='warn'>{html.escape(n)}</div>" for n in notes]
    if cmp is not None:
        parts.append("<h2 id='truth'>Compared with the truth</h2>")
        parts.append(_table(["quantity", "value"], comparison_rows(cmp)))
    parts.append("<h2 id='plots'>3D markers and skeleton</h2>")
    for name, alt in (("markers_3d.png", "3D markers"), ("skeleton_3d.png", "skeleton")):
        if name in rel:
            parts.append(_img(rel[name], alt))
    parts.append("<h2 id='markers'>Markers</h2>")
    parts.append("<p class='small'>views used: the views the 3D point rests on; whole views: those of them where "
                 "the bead looks whole; fit residual: the fitted skeleton's marker from the 3D point.</p>")
    parts.append(_table(*_marker_rows(result)))
    parts.append("<h2 id='pose'>Pose: joint angles</h2>")
    parts.append("<p class='small'>Local rotations as intrinsic XYZ Euler angles within the joint limits "
                 "(docs/skeleton.md); joint positions in the puppet frame.</p>")
    parts.append(_table(*_joint_rows(result)))
    parts.append("<h2 id='views'>Views</h2>")
    parts.append(_table(*_view_rows(result)))
    if overlays:
        parts.append("<p class='small'>Each photo (enlarged): bead candidates in grey, identified markers in their "
                     "colour, left-out observations in red, the 3D markers projected back as white crosses.</p>")
        parts.append("<div class='views'>")
        for f in overlays:
            parts.append(f"<figure>{_img(rel[f.name], f.stem)}<figcaption>{html.escape(f.stem)}</figcaption></figure>")
        parts.append("</div>")
    if result.timings_s:
        parts.append("<p class='small'>time: " + ", ".join(f"{html.escape(k)} {v:.2f} s"
                                                           for k, v in result.timings_s.items()) + "</p>")
    parts.append("<p class='small'>stillcap puppet outputs.</p></body></html>")
    return "\n".join(parts)


def write_html(result, folder, files) -> Path:
    """Write ``folder/report.html`` (:func:`report_html`) atomically."""
    return write_text(Path(folder) / "report.html", report_html(result, folder, files))
