"""The joint-angle plot: one panel per digit plus the hand's orientation (:func:`plot_joint_angles`)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from stillcap._checks import as_array, as_positive  # noqa: E402
from stillcap.body.hand import DIGITS  # noqa: E402
from stillcap.body.skeleton import Skeleton  # noqa: E402
from stillcap.files.atomic import atomic_path  # noqa: E402
from stillcap.report.hand._common import _digit, _size, _times, dof_labels  # noqa: E402


# --------------------------------------------------------------------------------------------
# joint angles
# --------------------------------------------------------------------------------------------
def _orientation_deg(root2world: np.ndarray) -> np.ndarray:
    """The hand's orientation in the field frame as intrinsic ZYX angles (yaw about z, pitch,
    roll), degrees, unwrapped over time; shape (n, 3)."""
    ang = Rotation.from_matrix(root2world[:, :3, :3]).as_euler("ZYX")
    return np.degrees(np.unwrap(ang, axis=0))


def plot_joint_angles(path, times, angles_deg, skeleton: Skeleton, *, keyframe_times=None, truth_times=None,
                      truth_angles_deg=None, root2world=None, truth_root2world=None,
                      release_time_s: float | None = None, size=(1200, 800), dpi: int = 100,
                      title: str = "Hand joint angles") -> Path:
    """Plot the hand's joint angles over time: one panel per digit and one for the hand's
    orientation; PNG.

    Parameters
    ----------
    path : str or PathLike
        A ``.png`` file.
    times : array_like, shape (n,)
        Seconds, increasing.
    angles_deg : array_like, shape (n, n_joints, 3)
        Twist, flexion, abduction (intrinsic XYZ Euler, as
        :meth:`~stillcap.body.Skeleton.limit_angles_deg` reads them), degrees; NaN = unknown.
        Each digit's panel shows its degrees of freedom (:func:`dof_labels`).
    skeleton : Skeleton
        The hand (:func:`~stillcap.body.hand.hand_skeleton` or a scaled one).
    keyframe_times : array_like, shape (K,), optional
        Flash times (s): markers on the curves and faint vertical lines.
    truth_times : array_like, shape (m,), optional
    truth_angles_deg : array_like, shape (m, n_joints, 3), optional
        Drawn dashed in the same colours.
    root2world : array_like, shape (n, 4, 4), optional
        The hand's pose; its orientation (ZYX yaw, pitch, roll in the field frame, unwrapped) fills
        the first panel. ``truth_root2world`` (m, 4, 4) likewise, dashed.
    release_time_s : float, optional
        Times are then in ms from release (a vertical line marks it).
    size : (int, int)
        Width and height in pixels.
    dpi : int
    title : str

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot_joint_angles writes PNG, got {path.name!r}")
    w, h = _size(size)
    dpi = int(as_positive(dpi, "dpi"))
    nj = skeleton.n_joints
    t = _times(times, "times")
    ang = as_array(angles_deg, (len(t), nj, 3), "angles_deg")
    r2w = None if root2world is None else as_array(root2world, (len(t), 4, 4), "root2world")
    keys = np.empty(0) if keyframe_times is None else _times(keyframe_times, "keyframe_times")
    tt = tang = tr2w = None
    if (truth_times is not None) != (truth_angles_deg is not None or truth_root2world is not None):
        raise ValueError("truth_times goes with truth_angles_deg and/or truth_root2world")
    if truth_times is not None:
        tt = _times(truth_times, "truth_times")
        if truth_angles_deg is not None:
            tang = as_array(truth_angles_deg, (len(tt), nj, 3), "truth_angles_deg")
        if truth_root2world is not None:
            tr2w = as_array(truth_root2world, (len(tt), 4, 4), "truth_root2world")
    t0 = 0.0 if release_time_s is None else float(release_time_s)

    def ms(x):
        return (np.asarray(x) - t0) * 1e3

    panels: list[tuple[str, list[tuple[str, np.ndarray | None, np.ndarray | None]]]] = []
    # (panel title, [(label, estimate (n,) or None, truth (m,) or None)])
    wrist = []
    if r2w is not None or tr2w is not None:
        est = _orientation_deg(r2w) if r2w is not None else None
        tru = _orientation_deg(tr2w) if tr2w is not None else None
        for a, name in enumerate(("yaw (about z)", "pitch (about y')", "roll (about x'')")):
            wrist.append((name, None if est is None else est[:, a], None if tru is None else tru[:, a]))
    panels.append(("hand orientation (field frame)", wrist))
    labels = dof_labels(skeleton)
    for d in DIGITS:
        rows = []
        for j, a, lab in labels:
            if _digit(skeleton.names[j]) == d:
                rows.append((lab.split(" ", 1)[1], ang[:, j, a], None if tang is None else tang[:, j, a]))
        panels.append((d, rows))

    fig, axes = plt.subplots(2, 3, figsize=(w / dpi, h / dpi), dpi=dpi, sharex=True)
    cmap = plt.get_cmap("tab10")
    for ax, (name, rows) in zip(axes.ravel(), panels):
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        for k in keys:
            ax.axvline(ms(k), color="0.8", lw=0.6, zorder=0)
        if release_time_s is not None:
            ax.axvline(0.0, color="k", lw=0.8, ls="-.", zorder=0)
        if not rows:
            ax.text(0.5, 0.5, "not given", ha="center", va="center", transform=ax.transAxes, color="0.5")
            continue
        for i, (lab, est, tru) in enumerate(rows):
            c = cmap(i % 10)
            if est is not None:
                ax.plot(ms(t), est, "-", color=c, lw=1.3, label=lab)
                if len(keys) and len(t) > 1:
                    ax.plot(ms(keys), np.interp(keys, t, est, left=np.nan, right=np.nan), "o", ms=4, color=c,
                            mec="k", mew=0.4)
                elif len(keys):
                    ax.plot(ms(t), est, "o", ms=4, color=c, mec="k", mew=0.4)
            if tru is not None:
                ax.plot(ms(tt), tru, "--", color=c, lw=1.0, label=None if est is not None else f"{lab} (truth)")
        ax.legend(fontsize=6, loc="best")
    xl = "time from release (ms)" if release_time_s is not None else "time (ms)"
    for ax in axes[1]:
        ax.set_xlabel(xl, fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("angle (deg)", fontsize=8)
    note = "solid: estimate" + ("; dashed: truth" if tt is not None else "") + ("; dots: flashes" if len(keys) else "")
    fig.suptitle(f"{title} ({note})", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return path
