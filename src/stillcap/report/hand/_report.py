"""The HTML report of a hand capture (:func:`write_hand_report`), and of a pipeline result with its
``hand.json`` (:func:`write_result_report`)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from stillcap._checks import as_array
from stillcap.body.skeleton import Animation, Skeleton
from stillcap.files.atomic import write_text
from stillcap.report.hand._angles import plot_joint_angles
from stillcap.report.hand._animation import write_hand_animation
from stillcap.report.hand._common import ANIMATION_FORMATS, Progress, dof_labels
from stillcap.report.pitch import _CSS, _fmt, _table, metric_unit


# --------------------------------------------------------------------------------------------
# HTML report
# --------------------------------------------------------------------------------------------
def _labels_text(labels) -> tuple[str, str]:
    """(count, names) of a flash's labelled markers: a mapping name -> label or a list of names."""
    if labels is None:
        return "", ""
    if isinstance(labels, Mapping):
        names = [f"{k}: {v}" if v not in (None, k) else str(k) for k, v in labels.items()]
    else:
        names = [str(x) for x in labels]
    return str(len(names)), ", ".join(names)


def _release_rows(release: Mapping, truth_release: Mapping | None) -> list[list[str]]:
    def show(x):
        if x is None:
            return ""
        if isinstance(x, (list, tuple, np.ndarray)):
            return "(" + ", ".join(_fmt(float(e), 4) for e in np.ravel(x)) + ")"
        return _fmt(x, 4) if not isinstance(x, str) else x

    rows = []
    for k, v in release.items():
        unit = metric_unit(k)
        if unit == "" and k.endswith("_m"):
            unit = "m"
        row = [k, show(v), unit]
        if truth_release is not None:
            row.append(show(truth_release.get(k)))
        rows.append(row)
    return rows


def _flash_angles(flashes: Sequence[Mapping], nj: int) -> np.ndarray | None:
    if not flashes or all(f.get("angles_deg") is None for f in flashes):
        return None
    out = np.full((len(flashes), nj, 3), np.nan)
    for i, f in enumerate(flashes):
        if f.get("angles_deg") is not None:
            out[i] = as_array(f["angles_deg"], (nj, 3), f"flashes[{i}]['angles_deg']")
    return out


def write_hand_report(folder, *, skeleton: Skeleton | None = None, animation: Animation | None = None,
                      flashes: Sequence[Mapping] = (), release: Mapping | None = None, ball_times=None,
                      ball_positions=None, markers=None, marker_colors=None, truth: Mapping | None = None,
                      release_time_s: float | None = None, animation_format: str = ".gif",
                      animation_options: Mapping | None = None, title: str = "Hand report",
                      messages: Sequence[str] = (), progress: Progress | None = None) -> dict[str, Path]:
    """Write a hand report folder: ``report.html``, ``hand.gif`` (or ``.mp4``) and
    ``joint_angles.png``.

    Parameters
    ----------
    folder : str or PathLike
        Created if missing.
    skeleton : Skeleton, optional
        The hand; default the animation's (one of the two is needed for joint angles).
    animation : Animation, optional
        The hand's motion (e.g. keyframes interpolated at 1000 fps). Gives the animation and
        the joint-angle curves.
    flashes : sequence of mapping
        One per flash, in time order. Keys (all optional but ``time_s``): ``time_s`` (s),
        ``held`` (bool, ball in the hand), ``n_markers`` (markers used by the fit), ``labels``
        (mapping marker name -> label, or a list of the labelled marker names), ``rms_mm`` (fit
        RMS, mm), ``angles_deg`` (n_joints, 3), ``success`` (bool), ``message`` (str).
        Their times are the keyframes.
    release : mapping, optional
        The release summary, ``key -> value`` (numbers, vectors or text); the unit is read from
        the key's suffix (``speed_mph``, ``time_s``, ``position_m`` ...).
    ball_times, ball_positions : array_like, shapes (B,), (B, 3), optional
        The ball (s, m), for the animation.
    markers, marker_colours :
        Glove markers for the animation (see :func:`write_hand_animation`).
    truth : mapping, optional
        Synthetic truth: ``times_s`` (m,), ``angles_deg`` (m, n_joints, 3), ``root2world``
        (m, 4, 4) for dashed curves; ``flash_angles_deg`` (n_flashes, n_joints, 3) for the
        error column of the angle table; ``release`` (mapping like ``release``).
    release_time_s : float, optional
        Times in ms from release.
    animation_format : ``".gif"`` or ``".mp4"``
    animation_options : mapping, optional
        More keywords for :func:`write_hand_animation` (``fps``, ``slowdown``, ``view``, ...).
    title : str
    messages : sequence of str
        Warnings shown at the top.
    progress : callable, optional
        ``progress(done, total, label)`` while the animation renders.

    Returns
    -------
    dict
        ``{"html": Path, "animation": Path, "joint_angles": Path}`` (only the files written).
    """
    out = Path(folder)
    fmt = animation_format if animation_format.startswith(".") else "." + animation_format
    if fmt.lower() not in ANIMATION_FORMATS:
        raise ValueError(f"animation_format must be one of {ANIMATION_FORMATS}, got {animation_format!r}")
    skel = skeleton or (animation.skeleton if animation is not None else None)
    flashes = [dict(f) for f in flashes]
    for i, f in enumerate(flashes):
        if "time_s" not in f:
            raise ValueError(f"flashes[{i}] has no 'time_s'")
    ftimes = np.array([float(f["time_s"]) for f in flashes])
    truth = dict(truth or {})
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}

    if animation is not None:
        opts = dict(animation_options or {})
        opts.setdefault("release_time_s", release_time_s)
        paths["animation"] = write_hand_animation(
            out / f"hand{fmt.lower()}", animation, ball_times=ball_times, ball_positions=ball_positions,
            keyframe_times=ftimes if len(ftimes) else None, markers=markers, marker_colors=marker_colors,
            progress=progress, **opts)

    fang = _flash_angles(flashes, skel.n_joints) if skel is not None else None
    if skel is not None and (animation is not None or fang is not None):
        if animation is not None:
            t, ang, r2w = animation.times, np.array([skel.limit_angles_deg(r) for r in animation.local_rotations]), \
                animation.root2world
        else:
            order = np.argsort(ftimes)
            t, ang, r2w = ftimes[order], fang[order], None
            if all(f.get("root2world") is not None for f in flashes):
                r2w = np.array([flashes[i]["root2world"] for i in order], float)
        tt = truth.get("times_s")
        paths["joint_angles"] = plot_joint_angles(
            out / "joint_angles.png", t, ang, skel, keyframe_times=ftimes if len(ftimes) else None,
            truth_times=tt, truth_angles_deg=truth.get("angles_deg") if tt is not None else None,
            root2world=r2w, truth_root2world=truth.get("root2world") if tt is not None else None,
            release_time_s=release_time_s)

    def tms(x):
        return _fmt(((x - release_time_s) if release_time_s is not None else x) * 1e3, 1)

    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>",
             "<p class='small'>Field frame, metres; times in ms"
             + (" from release" if release_time_s is not None else "") + ". See docs/hand-outputs.md.</p>"]
    for m in messages:
        parts.append(f"<div class='warn'>{html.escape(str(m))}</div>")
    if "animation" in paths:
        name = paths["animation"].name
        if fmt.lower() == ".mp4":
            parts.append(f"<h2>Slow motion</h2><video src='{html.escape(name)}' controls loop muted "
                         "style='max-width:100%'></video>")
        else:
            parts.append(f"<h2>Slow motion</h2><img src='{html.escape(name)}' alt='hand animation'>")
    if release:
        parts.append("<h2>Release</h2>")
        tr = truth.get("release")
        parts.append(_table(["quantity", "value", "unit"] + (["truth"] if tr is not None else []),
                            _release_rows(release, tr)))
    if flashes:
        parts.append("<h2>Flashes</h2>")
        rows = []
        for i, f in enumerate(flashes):
            n_lab, names = _labels_text(f.get("labels"))
            ok = f.get("success")
            status = "" if ok is None else ("ok" if ok else "failed")
            if f.get("message"):
                status = f"{status}: {f['message']}" if status else str(f["message"])
            held = f.get("held")
            rows.append([str(i + 1), tms(f["time_s"]), "" if held is None else ("held" if held else "released"),
                         _fmt(f.get("n_markers")), n_lab, _fmt(f.get("rms_mm"), 2), status, names])
        parts.append(_table(["flash", "time ms", "ball", "markers fitted", "labelled", "fit RMS mm", "status",
                             "labels"], rows))
    if fang is not None:
        parts.append("<h2>Joint angles per flash (degrees)</h2>")
        tfa = truth.get("flash_angles_deg")
        tfa = None if tfa is None else as_array(tfa, fang.shape, "truth['flash_angles_deg']")
        header = ["degree of freedom"] + [f"flash {i + 1}" for i in range(len(flashes))]
        header += ["max |error|"] if tfa is not None else []
        rows = []
        for j, a, lab in dof_labels(skel):
            row = [lab] + [_fmt(fang[i, j, a], 1) for i in range(len(flashes))]
            if tfa is not None:
                err = np.abs(fang[:, j, a] - tfa[:, j, a])
                row.append(_fmt(float(np.nanmax(err)) if np.any(np.isfinite(err)) else float("nan"), 2))
            rows.append(row)
        parts.append(_table(header, rows))
    if "joint_angles" in paths:
        parts.append(f"<h2>Joint angles over time</h2><img src='{html.escape(paths['joint_angles'].name)}' "
                     "alt='joint angles'>")
    parts.append("<p class='small'>stillcap hand outputs.</p></body></html>")
    paths["html"] = write_text(out / "report.html", "\n".join(parts))
    return paths


def write_result_report(result, folder, *, animation_format: str = ".gif", progress: Progress | None = None,
                        truth_arrays: dict | None = None) -> dict[str, Path]:
    """:func:`write_hand_report` for a :class:`~stillcap.pipelines.hand.HandResult`, plus
    ``hand.json`` (the result's :meth:`~stillcap.pipelines.hand.HandResult.to_dict`).

    Times are ms from the estimated release when there is one. With a studio truth in the
    capture (``truth_arrays``: :func:`stillcap.studio.compare.hand.truth_arrays` of it, for a
    result compared with it), the true joint angles are drawn dashed and per-flash errors listed.
    """
    from stillcap.io.project import dumps_json

    out = Path(folder)
    lab, seq, rel = result.labels, result.sequence, result.release
    fits = {int(k): i for i, k in enumerate(seq.flashes)} if seq is not None else {}
    held = result.ball_held()
    flashes, ks = [], []  # ks: the flash index of each entry
    for k in range(lab.n_flashes):
        names = [n for n, p in zip(lab.marker_names, lab.point_index[k]) if p >= 0]
        f = {"time_s": float(lab.times[k]), "labels": names, "n_markers": len(names),
             "rms_mm": float(lab.rms[k] * 1e3), "success": bool(lab.reconstructed[k]), "message": lab.skipped[k]}
        if int(lab.order[k]) in held:
            f["held"] = held[int(lab.order[k])]
        if k in fits:
            f["angles_deg"] = seq.angles_deg[fits[k]]
            f["root2world"] = seq.poses[fits[k]].root2world
        flashes.append(f)
        ks.append(k)
    # the angle table needs every flash: reconstructed ones only
    if any("angles_deg" in f for f in flashes):
        ks = [k for k, f in zip(ks, flashes) if "angles_deg" in f]
        flashes = [f for f in flashes if "angles_deg" in f]
    release = None
    t_rel = None
    if rel is not None and rel.success:
        t_rel = float(rel.t_release)
        release = {"time_s": rel.t_release, "time_sigma_s": rel.t_release_sigma, "speed_mph": rel.speed_mph,
                   "speed_sigma_mph": rel.speed_sigma_mph, "horizontal_deg": rel.horizontal_deg,
                   "vertical_deg": rel.vertical_deg, "direction_sigma_deg": rel.direction_sigma_deg,
                   "position_m": rel.position, "velocity_source": rel.velocity_source}
    truth = None
    tc = result.truth
    td = truth_arrays if tc is not None else None
    if td is not None and np.isfinite(tc.get("clock_offset_s", np.nan)) and seq is not None:
        tr = td
        match = tc["flash_match"]
        fa = np.full((len(flashes),) + tr["angles_deg"].shape[1:], np.nan)
        for i, k in enumerate(ks):
            if match[k] >= 0:
                fa[i] = tr["angles_deg"][match[k]]
        truth = {"times_s": tr["times"] - tc["clock_offset_s"], "angles_deg": tr["angles_deg"],
                 "root2world": tr["root2world"], "flash_angles_deg": fa}
    balls = result.balls
    paths = write_hand_report(
        out, skeleton=result.skeleton, animation=result.animation, flashes=flashes, release=release,
        ball_times=None if balls is None or not len(balls) else balls.times,
        ball_positions=None if balls is None or not len(balls) else balls.positions,
        markers=None, truth=truth, release_time_s=t_rel, animation_format=animation_format,
        title=f"Hand capture {result.capture.root.name if result.capture.root else ''}".strip(),
        messages=result.messages, progress=progress)
    paths["json"] = write_text(out / "hand.json", dumps_json(result.to_dict()) + "\n")
    return paths
