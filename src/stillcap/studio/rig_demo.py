"""The foundation demo: a synthetic 4-camera capture, calibrated and triangulated from its photos.

Stages (each a library call): render per-camera chessboard sets and a rig board set (studio) ->
intrinsics per camera and rig extrinsics by bundle adjustment (calibrate) -> render a marker
scene (studio) -> detect, label, match and triangulate its marker balls (pipelines.markers) ->
compare every recovered quantity with the truth.

The reconstruction never sees the truth. Calibration puts the world at camera 0, so the truth
is expressed in camera 0's frame for the comparison.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stillcap._checks import as_rng
from stillcap.calibrate import calibrate_intrinsics, calibrate_rig
from stillcap.calibrate.targets import Chessboard
from stillcap.camera import Rig
from stillcap.pipelines.markers import MarkerReconstruction, reconstruct_markers
from stillcap.studio.scenes import chessboard_set, marker_rig, marker_scene, rig_board_set


@dataclass
class RigDemoResult:
    true_rig: Rig
    calibrated_rig: Rig
    intrinsics_rms_px: dict
    rig_rms_px: float
    markers: MarkerReconstruction
    true_points_cam0: np.ndarray   # (M, 3) true centre of each recovered marker, camera-0 frame
    true_labels: list
    images: list = field(repr=False)
    timings_s: dict = field(default_factory=dict)

    @property
    def marker_errors_m(self) -> np.ndarray:
        return np.linalg.norm(self.markers.points - self.true_points_cam0, axis=1)

    def camera_rows(self) -> list[dict]:
        """Per camera: true vs recovered intrinsics and the camera-centre error (camera-0 frame)."""
        T0 = self.true_rig[0].world2cam
        rows = []
        for t, c in zip(self.true_rig, self.calibrated_rig):
            center = (T0 @ np.append(t.center, 1.0))[:3]
            rows.append({"camera": t.name,
                         "fx_true": t.K[0, 0], "fx": c.K[0, 0], "fy_true": t.K[1, 1], "fy": c.K[1, 1],
                         "cx_true": t.K[0, 2], "cx": c.K[0, 2], "cy_true": t.K[1, 2], "cy": c.K[1, 2],
                         "k1_true": t.dist[0], "k1": c.dist[0],
                         "centre_error_mm": 1e3 * float(np.linalg.norm(c.center - center)),
                         "intrinsics_rms_px": self.intrinsics_rms_px[t.name]})
        return rows

    def to_dict(self) -> dict:
        e = self.marker_errors_m * 1e3
        return {"cameras": self.camera_rows(), "rig_rms_px": self.rig_rms_px,
                "markers": [{**m, "true_label": tl, "error_mm": float(err)}
                            for m, tl, err in zip(self.markers.to_dict()["markers"], self.true_labels, e)],
                "marker_error_mm": {"mean": float(np.mean(e)) if len(e) else None,
                                    "max": float(np.max(e)) if len(e) else None},
                "timings_s": self.timings_s}


def run_rig_demo(seed: int = 0, n_cameras: int = 4, board_views: int = 12, n_balls: int = 12,
                 out: Path | None = None, progress=None) -> RigDemoResult:
    """Render, calibrate, triangulate and compare (see the module docstring).

    ``progress(task, done, total)`` is called as work advances; with ``out`` the rendered
    captures are written there as capture folders (``boards/``, ``rig-boards/``, ``markers/``)
    together with the calibrated ``rig.json``.
    """
    rng = as_rng(seed)
    tick = time.perf_counter()
    timings = {}

    def step(name):
        nonlocal tick
        now = time.perf_counter()
        timings[name] = round(now - tick, 3)
        tick = now

    def report(task):
        return None if progress is None else (lambda i, n, *_: progress(task, i, n))

    true_rig = marker_rig(n_cameras, rng=rng)
    # 1. intrinsics: each camera photographs a board held close, filling its view
    board = Chessboard(9, 6, 0.025)
    sets = [chessboard_set(cam, board_views, board, rng=rng, progress=report(f"render boards {cam.name}"))
            for cam in true_rig]
    shared = rig_board_set(true_rig, board_views, Chessboard(9, 6, 0.06), rng=rng, spread=0.5,
                           progress=report("render rig boards"))
    step("render calibration photos")
    intr = [calibrate_intrinsics(s.images, s.target, camera_name=cam.name) for s, cam in zip(sets, true_rig)]
    for r in intr:
        if not r.success:
            raise ValueError(f"intrinsic calibration of {r.camera.name} failed: {r.images_skipped}")
    cal = calibrate_rig(shared.images, shared.target, cameras=Rig([r.camera for r in intr]),
                        progress=report("calibrate rig"))
    if not cal.success:
        raise ValueError(f"rig calibration failed: {cal.message}")
    step("calibrate")
    # 2. a marker scene photographed by the (true) rig, reconstructed with the calibrated one
    scene = marker_scene(true_rig, n_balls, rng=rng, progress=report("render markers"))
    step("render marker scene")
    rec = reconstruct_markers(cal.rig, scene.images)
    step("reconstruct markers")

    truth = scene.truth
    T0 = true_rig[0].world2cam
    idx = [i for i, k in enumerate(truth.ball_kinds) if k == "marker"]
    centers = truth.ball_centers[idx] @ T0[:3, :3].T + T0[:3, 3]
    names = [truth.ball_names[i] for i in idx]
    nearest = [int(np.argmin(np.linalg.norm(centers - p, axis=1))) for p in rec.points]
    result = RigDemoResult(true_rig, cal.rig, {r.camera.name: r.rms_px for r in intr}, cal.rms_px, rec,
                           centers[nearest].reshape(-1, 3), [names[i] for i in nearest], scene.images, timings)
    if out is not None:
        out = Path(out)
        for s, cam in zip(sets, true_rig):
            cap, files = s.to_capture()
            cap.save(out / "boards" / cam.name, files)
        cap, files = shared.to_capture()
        cap.save(out / "rig-boards", files)
        cap, files = scene.to_capture()
        cap.save(out / "markers", files)
        cal.rig.save(out / "rig-calibrated.json")
        step("write captures")
    return result
