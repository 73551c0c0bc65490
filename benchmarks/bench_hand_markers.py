"""Hand markers (issue 5, stage "Markers"): coloured-blob detection and 3D points from the
studio's multi-exposure hand captures, with and without the half-lit centroid correction.

    python benchmarks/bench_hand_markers.py [--seeds 5] [--first 0] [--size 2560x1920] [--supersample 3]

Per seed: one hand capture (4 cameras, 4-5 flashes, the true rig), JPEG 92 encoded and decoded
as the CLI writes it; blobs by ``find_color_markers`` with the ball discs of every flash
excluded (the pitch pipeline finds them; here their truth); 3D points by
``triangulate_color_markers`` with the strobe's position (corrected) and without (raw).

Columns:
- ``vis2``: truth markers (of all flashes) whose centre is visible in 2+ cameras;
  ``found``: of those, how many have a point of their colour within 3 mm;
- ``pts``: 3D points; ``wrong``: points farther than 3 mm from every truth marker of their colour
  (``flagged``: of those, how many the triangulation reports as ``partly_hidden``);
- ``rms``/``max`` (mm): error of the other points, corrected / raw;
- ``clean``: RMS (mm) of the points whose every used blob is an isolated, fully uncovered
  marker (truth ``markers_isolated`` and ``markers_coverage`` = 1): the stage's accuracy when
  the blob is the whole marker; the rest are partly hidden by the glove (their centroid moves
  by up to ~1.5 px at 1280x960, which no model of an unhidden sphere removes);
- ``unflagged``: RMS (mm) and count of the right points not flagged ``partly_hidden`` (what a
  later stage keeps if it drops the flagged ones);
- ``detect``/``tri``/``decode`` (ms): blob detection of the 4 photos, triangulation
  (corrected), decoding the 4 JPEGs.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from rich.console import Console
from rich.table import Table

from stillcap.body.hand import HAND_COLORS
from stillcap.detect.color_markers import find_color_markers
from stillcap.geometry.marker_points import triangulate_color_markers
from stillcap.studio.hand import hand_capture


def ball_discs(cam, truth, grow_px=2.0):
    """Ball images of every flash in one camera (centres, radii), hidden or not."""
    c = truth.ball2world[:, :3, 3]
    z = cam.world_to_cam(c)[:, 2]
    return cam.project(c), cam.K[0, 0] * truth.ball["radius"] / z + grow_px


def score(mp, truth, rig):
    """Errors (mm) of the points against the nearest same-colour truth marker, and flags."""
    T = truth.markers.reshape(-1, 3)
    tc = np.tile(np.array(truth.marker_colors), len(truth.markers))
    d = np.linalg.norm(mp.points[:, None] - T[None], axis=2)
    d = np.where(mp.colors[:, None] == tc[None], d, np.inf)
    nearest = d.argmin(axis=1) if len(mp) else np.zeros(0, int)
    err = (d.min(axis=1) if len(mp) else np.zeros(0)) * 1000
    cov = truth.markers_coverage.reshape(len(rig), -1)
    iso = truth.markers_isolated.reshape(len(rig), -1)
    clean = np.array([np.all((cov[u, k] > 0.999) & iso[u, k]) for u, k in zip((mp.blob_index >= 0).T, nearest)], bool)
    vis2 = (truth.markers_visible.sum(axis=0) >= 2).ravel()
    best = np.full(len(T), np.inf)
    np.minimum.at(best, nearest, err)
    return err, clean, int(vis2.sum()), int(np.sum(best[vis2] <= 3.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--size", default="2560x1920")
    ap.add_argument("--supersample", type=int, default=3)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))
    con = Console(width=200)
    tab = Table(title=f"hand markers, {w}x{h}, JPEG 92, true rig")
    for c in ("seed", "blobs/img", "vis2", "found", "pts", "wrong", "flagged", "rms", "max", "clean", "unflagged",
              "raw rms", "raw max",
              "raw clean", "detect ms", "tri ms", "decode ms"):
        tab.add_column(c, justify="right")
    tot = {"err": [], "raw": [], "clean": [], "raw_clean": [], "wrong": 0, "flagged": 0, "unflagged": [], "pts": 0, "vis2": 0, "found": 0}
    for seed in range(args.first, args.first + args.seeds):
        hc = hand_capture(seed, image_size=(w, h), supersample=args.supersample)
        rig, tr = hc.rig.rig, hc.truth
        jpgs = [cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, 92])[1] for im in hc.images]
        t0 = time.perf_counter()
        images = [cv2.imdecode(j, cv2.IMREAD_COLOR) for j in jpgs]
        t_dec = time.perf_counter() - t0
        t0 = time.perf_counter()
        blobs = [find_color_markers(im, HAND_COLORS, exclude=ball_discs(cam, tr)) for cam, im in zip(rig, images)]
        t_det = time.perf_counter() - t0
        t0 = time.perf_counter()
        mp = triangulate_color_markers(rig, hc.rig.pairs, blobs, light_position=hc.rig.light.position)
        t_tri = time.perf_counter() - t0
        raw = triangulate_color_markers(rig, hc.rig.pairs, blobs)
        err, clean, vis2, found = score(mp, tr, rig)
        err_r, clean_r, _, _ = score(raw, tr, rig)
        ok, ok_r = err <= 3.0, err_r <= 3.0
        rms = lambda e: float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")  # noqa: E731
        ph = mp.partly_hidden
        tab.add_row(str(seed), f"{np.mean([len(b) for b in blobs]):.0f}", str(vis2), str(found), str(len(mp)),
                    str(int((~ok).sum())), str(int((~ok & ph).sum())), f"{rms(err[ok]):.2f}", f"{err[ok].max():.2f}",
                    f"{rms(err[ok & clean]):.2f}", f"{rms(err[ok & ~ph]):.2f} ({int((ok & ~ph).sum())})",
                    f"{rms(err_r[ok_r]):.2f}", f"{err_r[ok_r].max():.2f}", f"{rms(err_r[ok_r & clean_r]):.2f}",
                    f"{t_det * 1000:.0f}", f"{t_tri * 1000:.0f}", f"{t_dec * 1000:.0f}")
        tot["err"] += list(err[ok])
        tot["raw"] += list(err_r[ok_r])
        tot["clean"] += list(err[ok & clean])
        tot["raw_clean"] += list(err_r[ok_r & clean_r])
        tot["wrong"] += int((~ok).sum())
        tot["flagged"] += int((~ok & ph).sum())
        tot["unflagged"] += list(err[ok & ~ph])
        tot["pts"] += len(mp)
        tot["vis2"] += vis2
        tot["found"] += found
    a = {k: np.array(v) for k, v in tot.items() if isinstance(v, list)}
    tab.add_row("all", "", str(tot["vis2"]), str(tot["found"]), str(tot["pts"]), str(tot["wrong"]), str(tot["flagged"]),
                f"{rms(a['err']):.2f}", f"{a['err'].max():.2f}", f"{rms(a['clean']):.2f}",
                f"{rms(a['unflagged']):.2f} ({len(a['unflagged'])})", f"{rms(a['raw']):.2f}",
                f"{a['raw'].max():.2f}", f"{rms(a['raw_clean']):.2f}", "", "", "")
    con.print(tab)


if __name__ == "__main__":
    main()
