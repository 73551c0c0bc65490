"""Why markers seen by two or more cameras got no right label (issue 12, the hand goal): each
(flash, marker) pair that the studio's truth shows in 2+ cameras, counted once under the first
stage that lost it. Used by ``bench_hand_matching.py --causes``.

Stages, in pipeline order (the first that fails names the cause):

- ``flash not found``: no result flash matched the truth's flash (``compare_with_truth``'s flash
  match); ``bench_hand_matching.py``'s ``seen2`` leaves these out, so they are counted apart;
- ``detect: <2 cams``: fewer than two cameras that see the marker's centre have a blob of its
  colour within the gate of its true lit centroid (``markers_lit_px``); the gate is the
  marker's projected radius (at least 2 px). Sub-causes: ``on the ball`` (a camera that missed
  it sees it on the ball's disc, which stage 2 masks out; the result's blobs hold such blobs
  only when the pose-guided search used them), ``merged`` (a camera that missed it
  has the marker's disc within 2 px of another's, ``markers_isolated`` false), ``hidden``
  (coverage below 0.5 in a camera that missed it), ``other``;
- ``3D: no point``: blobs in 2+ cameras but no 3D point of its colour within the label
  tolerance (10 mm). Sub-causes: ``left out`` (the pipeline's partly hidden, ambiguous points
  dropped before labelling), ``blob taken`` (a blob near the truth belongs to another point),
  ``unmatched`` (its blobs are in no point);
- ``flash without pose``: a point, in a flash with no pose;
- ``unlabelled``: a point in a posed flash, with no label. Sub-causes ``partly hidden 2 views``
  (the unconfirmed points), ``other``;
- ``wrong label``: a point whose label names another marker.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from stillcap.files.jsonable import from_jsonable
from stillcap.geometry.marker_points import triangulate_color_markers
from stillcap.studio.compare.hand import LABEL_TOLERANCE_M, truth_arrays

CAUSES = ("flash not found", "detect: <2 cams", "3D: no point", "flash without pose", "unlabelled", "wrong label")


def _on_ball(balls, camera: int, px) -> bool:
    """The pixel lies on a ball disc of the camera (stage 2 masks those out)."""
    if balls is None or not len(balls) or not np.all(np.isfinite(px)):
        return False
    c, r = balls.ball_discs_px(camera)
    return bool(len(r) and np.any(np.linalg.norm(c - px, axis=1) < r + 1.0))


def causes(result, truth: dict, match, radius_m: float = 0.005) -> Counter:
    """Counter of ``"cause"`` and ``"cause / sub-cause"`` over the truth's (flash, marker) pairs
    seen by 2+ cameras that have no right label; ``"seen2"`` and ``"right"`` count all of them
    and the right-labelled ones (over all truth flashes, matched or not)."""
    tr = truth_arrays(truth)
    f = truth["flashes"]
    nc_t = len(truth["cameras"])
    n_t, nm = tr["markers"].shape[:2]
    lit = from_jsonable(f["markers_lit_px"]).reshape(nc_t, n_t, nm, 2)
    cov = from_jsonable(f["markers_coverage"]).reshape(nc_t, n_t, nm)
    iso = from_jsonable(f["markers_isolated"]).reshape(nc_t, n_t, nm).astype(bool)
    vis = tr["visible"]
    colours = list(truth["marker_colours"])
    rig = result.capture.rig
    cam_of = [rig.names.index(c) for c in truth["cameras"]]
    blobs, pts, lab = result.blobs, result.points, result.labels
    # the pipeline's points before its partly-hidden-and-ambiguous cut
    light = result.capture.meta.get("strobe_position_m")
    pairs = {p: tuple(c) for p, c in result.capture.meta["pairs"].items()}
    raw = triangulate_color_markers(rig, pairs, blobs, light_position=light, radius_m=radius_m)
    used_blob = [set(pts.blob_index[k][pts.blob_index[k] >= 0].tolist()) for k in range(len(rig.names))]
    point_label = lab.labels()  # (N, 2) flash, marker
    k_of = {int(j): k for k, j in enumerate(match) if j >= 0}
    out = Counter()
    for j in range(n_t):
        for m in range(nm):
            if vis[:, j, m].sum() < 2:
                continue
            out["seen2"] += 1
            k = k_of.get(j)
            if k is not None and lab.point_index[k, m] >= 0:
                d = np.linalg.norm(tr["markers"][j] - lab.positions[k, m], axis=1)
                if int(np.nanargmin(d)) == m and d[m] <= LABEL_TOLERANCE_M:
                    out["right"] += 1
                    continue
            if k is None:
                out["flash not found"] += 1
                continue
            # detection: a blob of its colour near the true lit centroid, per camera that sees it
            near = {}
            missed = []
            for t in np.flatnonzero(vis[:, j, m]):
                c = cam_of[t]
                b = blobs[c]
                cam = rig[c]
                z = cam.world_to_cam(tr["markers"][j, m][None])[0, 2]
                gate = max(2.0, cam.K[0, 0] * radius_m / z)
                sel = np.flatnonzero(np.asarray(b.colors, object) == colours[m])
                if len(sel):
                    dd = np.linalg.norm(b.centers[sel] - lit[t, j, m], axis=1)
                    if dd.min() <= gate:
                        near[c] = int(sel[np.argmin(dd)])
                        continue
                missed.append(t)
            if len(near) < 2:
                sub = ("on the ball" if any(_on_ball(result.balls, cam_of[t], lit[t, j, m]) for t in missed) else
                       "merged" if any(not iso[t, j, m] for t in missed) else
                       "hidden" if any(cov[t, j, m] < 0.5 for t in missed) else "other")
                out["detect: <2 cams"] += 1
                out[f"detect: <2 cams / {sub}"] += 1
                continue
            same = pts.colors == colours[m]
            dp = np.linalg.norm(pts.points - tr["markers"][j, m], axis=1)
            dp = np.where(same, dp, np.inf)
            if not len(dp) or dp.min() > LABEL_TOLERANCE_M:
                draw = np.where(raw.colors == colours[m],
                                np.linalg.norm(raw.points - tr["markers"][j, m], axis=1), np.inf)
                sub = ("left out" if len(draw) and draw.min() <= LABEL_TOLERANCE_M else
                       "blob taken" if any(near[c] in used_blob[c] for c in near) else "unmatched")
                out["3D: no point"] += 1
                out[f"3D: no point / {sub}"] += 1
                continue
            p = int(np.argmin(dp))
            fk = point_label[p, 0]
            if fk < 0:
                if not lab.reconstructed[k]:
                    out["flash without pose"] += 1
                else:
                    sub = "partly hidden 2 views" if (pts.partly_hidden[p] and pts.n_views[p] == 2) else "other"
                    out["unlabelled"] += 1
                    out[f"unlabelled / {sub}"] += 1
            else:
                out["wrong label"] += 1
    return out


def print_table(rows: dict) -> None:
    """``rows``: name -> Counter (from :func:`causes`); one column per name plus the total."""
    names = list(rows)
    tot = sum(rows.values(), Counter())
    keys = ["seen2", "right"] + [c for c in CAUSES for c in [c] + sorted(k for k in tot if k.startswith(c + " / "))]
    print(f"{'cause':<38}" + "".join(f"{n:>8}" for n in names) + f"{'all':>8}{'% seen2':>9}")
    for key in keys:
        v = [rows[n].get(key, 0) for n in names]
        print(f"{key:<38}" + "".join(f"{x:>8}" for x in v) + f"{tot.get(key, 0):>8}"
              f"{100 * tot.get(key, 0) / max(tot['seen2'], 1):>9.1f}")
