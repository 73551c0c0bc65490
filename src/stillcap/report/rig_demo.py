"""Plot of the rig demo: camera views with detections, and the 3D scene with cameras."""

from __future__ import annotations

from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from stillcap.files.atomic import atomic_path  # noqa: E402


def plot_rig_demo(res, path) -> Path:
    """Two rendered views with the matched markers, and a 3D view of cameras, truth and result."""
    fig = plt.figure(figsize=(15, 5.2))
    x2d = res.markers.points_2d
    for k in range(2):
        ax = fig.add_subplot(1, 3, k + 1)
        ax.imshow(cv2.cvtColor(res.images[k], cv2.COLOR_BGR2RGB))
        ok = np.isfinite(x2d[k, :, 0])
        ax.scatter(x2d[k, ok, 0], x2d[k, ok, 1], s=120, facecolors="none", edgecolors="w", linewidths=1)
        for lab, p in zip(np.array(res.markers.labels, object)[ok], x2d[k, ok]):
            ax.annotate(lab, p, xytext=(8, -8), textcoords="offset points", color="w", fontsize=7)
        ax.set_title(f"{res.calibrated_rig[k].name}: rendered photo, matched markers")
        ax.set_axis_off()
    ax = fig.add_subplot(1, 3, 3, projection="3d")
    centers = np.array([c.center for c in res.calibrated_rig])
    ax.scatter(*centers.T, marker="^", s=60, c="k", label="calibrated cameras")
    for c in res.calibrated_rig:
        axis = c.R[2] * 0.4
        ax.plot(*np.stack([c.center, c.center + axis]).T, "k-", lw=0.8)
        ax.text(*c.center, c.name, fontsize=7)
    ax.scatter(*res.true_points_cam0.T, s=50, facecolors="none", edgecolors="g", label="truth")
    ax.scatter(*res.markers.points.T, s=8, c="r", label="triangulated")
    err = res.marker_errors_m * 1e3
    ax.set_title(f"{len(err)} markers, mean error {err.mean():.2f} mm (camera-0 frame, m)")
    ax.legend(fontsize=7, loc="upper left")
    allp = np.concatenate([centers, res.true_points_cam0.reshape(-1, 3)])
    ax.set_box_aspect(np.ptp(allp, axis=0) + 1e-3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return Path(path)
