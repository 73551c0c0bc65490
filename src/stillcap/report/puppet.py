"""Pictures of a puppet result: each photo with its identified markers, and 3D plots.

- :func:`overlay_view`: the photo with every bead candidate (thin grey circle), each identified
  marker (circle in its reference colour and its name), observations the triangulation left
  out (red: partly hidden bead or disagreeing view) and the 3D markers projected back (small
  white crosses) - the thesis's "processed photo", with more to see.
- :func:`plot_markers_3d`: the 3D markers with the turn axis, from four sides (the thesis's
  360-degree view), missing markers listed.
- :func:`plot_skeleton_3d`: the fitted skeleton (and the thesis's, and the truth when known)
  from four sides.
- :func:`write_report`: all of them into a folder, with ``report.html``
  (:mod:`stillcap.report.puppet_html`).

Every file is written atomically (:func:`stillcap.files.atomic.atomic_path`); matplotlib runs
with the Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stillcap.files.atomic import atomic_path  # noqa: E402

__all__ = ["overlay_view", "plot_markers_3d", "plot_skeleton_3d", "write_image", "write_report"]

_RED = (40, 40, 230)


def _marker_bgr(markerset) -> np.ndarray:
    return np.round(np.asarray(markerset.rgb)[:, ::-1] * 255).astype(int)


def overlay_view(image, result, view: int, scale: int = 2) -> np.ndarray:
    """The photo of one view with its candidates, identified markers and reprojected 3D markers.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3)
        The view's photo (BGR).
    result : PuppetResult
    view : int
        View index.
    scale : int
        Enlargement (the beads are 5-7 px), nearest-neighbour.

    Returns
    -------
    ndarray, shape (scale H, scale W, 3), uint8 BGR
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    out = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    out = np.ascontiguousarray(out)
    s = float(scale)

    def px(p):  # (x, y) with origin at the top-left pixel centre -> enlarged pixel centre
        return int(round((p[0] + 0.5) * s - 0.5)), int(round((p[1] + 0.5) * s - 0.5))

    m = result.markers
    colors = _marker_bgr(result.markerset)
    if result.views is not None and result.views[view] is not None:
        c = result.views[view].circles
        for p, r in zip(c.centers, c.radii):
            cv2.circle(out, px(p), int(round(r * s)), (110, 110, 110), 1, cv2.LINE_AA)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for k, name in enumerate(m.names):
        p = m.observations[view, k]
        if not np.all(np.isfinite(p)):
            continue
        col = tuple(int(v) for v in colors[k])
        r = int(round(7 * s))
        if m.used[view, k]:
            cv2.circle(out, px(p), r, col, 2, cv2.LINE_AA)
            label_col = col
        else:
            cv2.circle(out, px(p), r, _RED, 2, cv2.LINE_AA)
            x, y = px(p)
            cv2.line(out, (x - r, y - r), (x + r, y + r), _RED, 1, cv2.LINE_AA)
            label_col = _RED
        x, y = px(p)
        text = name + (" (partial)" if m.partial[view, k] else " (outlier)" if m.outlier[view, k] else "")
        cv2.putText(out, text, (x + r + 2, y - r // 2), font, 0.38 * s / 2 + 0.12, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(out, text, (x + r + 2, y - r // 2), font, 0.38 * s / 2 + 0.12, label_col, 1, cv2.LINE_AA)
    ok = m.ok
    if ok.any():
        proj = result.rig[view].project(m.points[ok])
        for p in proj:
            if np.all(np.isfinite(p)):
                x, y = px(p)
                cv2.drawMarker(out, (x, y), (255, 255, 255), cv2.MARKER_CROSS, int(4 * s), 1, cv2.LINE_AA)
    angle = result.angles_deg[view]
    title = f"{result.view_names[view]}" + (f"  {angle:g} deg" if angle is not None else "") + \
        f"  identified {int(np.isfinite(m.observations[view, :, 0]).sum())}, used {int(m.used[view].sum())}"
    cv2.putText(out, title, (8, 22), font, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, title, (8, 22), font, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def write_image(path, image) -> Path:
    """Write an image atomically (format from the suffix)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image):
            raise ValueError(f"OpenCV could not write {path}")
    return path


#: Views of the 3D plots: the turntable camera angle they look from (degrees) and a title.
_SIDES = ((0, "from the camera at 0 deg (front)"), (90, "at 90 deg"), (180, "at 180 deg (back)"), (270, "at 270 deg"))


def _xzy(p):
    """Puppet frame (x, y up, z) -> matplotlib's z-up axes (x, -z, y): a rotation, not a mirror."""
    p = np.asarray(p)
    return p[..., 0], -p[..., 2], p[..., 1]


def _azimuth(turn_deg: float) -> float:
    """matplotlib azimuth that looks from the turntable camera at ``turn_deg`` (its centre is at
    ``(-sin a, ., cos a)`` in the puppet frame)."""
    return -90.0 - turn_deg


def _frame_axes(ax, pts, title, turn_deg: float = 0.0):
    """A cube around ``pts`` (equal aspect), ticks in mm (four per axis at most); the axis that
    points at the viewer (seen end-on, its ticks would pile up) keeps its grid but no labels."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ax.set_title(title, fontsize=9)
    mm = FuncFormatter(lambda v, _: f"{v * 1e3:.0f}")
    axes = ((ax.xaxis, "x (mm)"), (ax.yaxis, "-z (mm)"), (ax.zaxis, "y (mm)"))
    a = np.radians(_azimuth(turn_deg))
    end_on = ax.yaxis if abs(np.sin(a)) > abs(np.cos(a)) else ax.xaxis
    for axis, label in axes:
        axis.set_major_locator(MaxNLocator(4))
        axis.set_major_formatter(mm)
        axis.set_label_text("" if axis is end_on else label, fontsize=7)
        if axis is end_on:
            axis.set_ticklabels([])
    ax.zaxis.set_rotate_label(False)  # upright from every side (matplotlib turns it upside down on the left)
    ax.zaxis.label.set_rotation(90)
    ax.tick_params(labelsize=6, pad=0)
    pts = np.asarray(pts)[np.all(np.isfinite(pts), axis=1)]
    if len(pts):
        q = np.stack(_xzy(pts), axis=1)
        c = 0.5 * (q.min(axis=0) + q.max(axis=0))
        r = 0.5 * max(float(np.ptp(q, axis=0).max()), 0.05) * 1.1
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))


def plot_markers_3d(result, path, truth=None) -> Path:
    """The 3D markers with the turn axis, seen from four sides (the thesis's 360-degree view).

    Parameters
    ----------
    result : PuppetResult
    path : path
        PNG to write.
    truth : PuppetTruth, optional
        Also draw the true bead centres (hollow circles).
    """
    m = result.markers
    colors = np.asarray(result.markerset.rgb)
    fig = plt.figure(figsize=(13, 4.2))
    top = float(np.nanmax(m.points[:, 1])) if m.ok.any() else 0.2
    for i, (az, label) in enumerate(_SIDES):
        ax = fig.add_subplot(1, 4, i + 1, projection="3d")
        ax.plot([0, 0], [0, 0], [0, max(top, 0.2) * 1.05], "k--", lw=0.8, label="turn axis")
        ok = m.ok
        ax.scatter(*_xzy(m.points[ok]), c=colors[ok], s=36, edgecolors="k", linewidths=0.4, depthshade=False,
                   label="triangulated")
        if truth is not None:
            ax.scatter(*_xzy(truth.marker_positions), s=70, facecolors="none", edgecolors="0.5", linewidths=0.6,
                       depthshade=False, label="truth")
        if i == 0:
            for name, p in zip(np.array(m.names)[ok], m.points[ok]):
                ax.text(*_xzy(p), " " + name, fontsize=5)
        ax.view_init(elev=10, azim=_azimuth(az))
        _frame_axes(ax, m.points if truth is None else np.vstack([m.points, truth.marker_positions]), label, az)
        if i == 0:
            ax.legend(fontsize=6, loc="upper left")
    miss = ", ".join(result.missing) or "none"
    fig.suptitle(f"3D markers (puppet frame, y up, mm): {int(m.ok.sum())} of {len(m.names)}; "
                 f"seen in fewer than 2 views: {miss}", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return Path(path)


def _bones(ax, pose, style, color, label):
    pos = pose.positions
    first = True
    for j, p in enumerate(pose.skeleton.parents):
        if p < 0:
            continue
        seg = np.stack([pos[p], pos[j]])
        ax.plot(*_xzy(seg), style, color=color, lw=1.6 if style == "-" else 1.0, label=label if first else None)
        first = False
    ax.scatter(*_xzy(pos), s=8, color=color, depthshade=False)


def plot_skeleton_3d(result, path, truth=None, thesis: bool = True) -> Path:
    """The fitted skeleton (and the thesis's bone-direction pose, and the truth) from four sides.

    Parameters
    ----------
    result : PuppetResult
    path : path
        PNG to write.
    truth : PuppetTruth, optional
    thesis : bool
        Also draw the thesis's pose (dashed).
    """
    m = result.markers
    fig = plt.figure(figsize=(13, 4.2))
    pts = [result.pose.positions, m.points]
    for i, (az, label) in enumerate(_SIDES):
        ax = fig.add_subplot(1, 4, i + 1, projection="3d")
        ax.plot([0, 0], [0, 0], [0, 0.22], "k:", lw=0.6)
        if truth is not None:
            tp = truth.pose(result.pose.skeleton)
            _bones(ax, tp, "-", "0.75", "truth")
            pts.append(tp.positions)
        if thesis and result.options.pose == "fit":
            _bones(ax, result.thesis_pose, "--", "tab:orange", "thesis (bone directions)")
        _bones(ax, result.pose, "-", "tab:blue", "fitted" if result.options.pose == "fit" else "thesis")
        ok = m.ok
        ax.scatter(*_xzy(m.points[ok]), c=np.asarray(result.markerset.rgb)[ok], s=18, edgecolors="k",
                   linewidths=0.3, depthshade=False)
        ax.view_init(elev=10, azim=_azimuth(az))
        _frame_axes(ax, np.vstack(pts), label, az)
        if i == 0:
            ax.legend(fontsize=6, loc="upper left")
    fit = result.fit
    fig.suptitle(f"skeleton (puppet frame, y up, mm): fit RMS {fit.rms_m * 1e3:.2f} mm over {fit.n_markers} markers",
                 fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return Path(path)


def write_report(result, images, out, truth=None, overlays: bool = True, progress=None) -> list[Path]:
    """Overlays of every view (``out/overlays/<view>.png``), ``markers_3d.png``, ``skeleton_3d.png``
    and ``report.html`` (:func:`stillcap.report.puppet_html.write_html`, linking them).

    Parameters
    ----------
    result : PuppetResult
    images : sequence of ndarray
        The photos, view order.
    out : path
        Folder (created).
    truth : PuppetTruth, optional
    overlays : bool
    progress : callable(done, total, label), optional
        Called after each file.

    Returns
    -------
    list of Path
        The files written, ``report.html`` last.
    """
    from stillcap.report.puppet_html import write_html

    out = Path(out)
    files = []
    n_over = len(images) if overlays and images is not None else 0
    total = n_over + 3

    def done(label):
        if progress is not None:
            progress(len(files), total, label)

    for k in range(n_over):
        name = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(result.view_names[k]))
        files.append(write_image(out / "overlays" / f"{k:02d}_{name}.png", overlay_view(images[k], result, k)))
        done(f"overlay {k + 1} of {n_over}")
    files.append(plot_markers_3d(result, out / "markers_3d.png", truth))
    done("markers_3d.png")
    files.append(plot_skeleton_3d(result, out / "skeleton_3d.png", truth))
    done("skeleton_3d.png")
    files.append(write_html(result, out, files))
    done("report.html")
    return files
