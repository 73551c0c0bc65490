"""The hand pipeline's stages, in order (``docs/hand-pipeline.md`` tells the story); each a
plain function over arrays and dataclasses that appends what went wrong to ``messages``:

1. :func:`find_ball`            the white ball's centre per flash from all views
                                (:func:`~stillcap.pipelines.hand.ball.hand_ball_positions`)
2. :func:`find_glove_markers`   colour intervals, connected regions, centroids, the ball's discs
                                masked out (:func:`~stillcap.detect.color_markers.find_color_markers`)
3. :func:`triangulate_glove_markers`  epipolar matching per stereo pair, triangulation, the
                                half-lit centroid bias removed
                                (:func:`~stillcap.geometry.marker_points.triangulate_color_markers`)
4. :func:`label_markers`        3D markers clustered into hand poses per flash and labelled
                                (:func:`~stillcap.body.hand_label.label_hand_markers`)
5. :func:`fit_poses`            hand poses per flash and the animation between them
                                (:func:`~stillcap.body.hand_track.fit_hand_sequence`,
                                :func:`~stillcap.body.hand_track.interpolate_animation`)
6. :func:`release_and_spin`     the ball's flashes on the hand's clock, the release
                                (:func:`~stillcap.ball.release.estimate_release`) and the free
                                ball's spin (:func:`~stillcap.pipelines.hand.ball.hand_ball_spin`)
7. :func:`check_hand`           the self-checks: hand size, fit residuals per marker and digit
                                against the noise, markers left unlabelled
                                (:func:`~stillcap.body.hand_checks.hand_self_checks`)

:func:`~stillcap.pipelines.hand.analyse_hand` runs them in this order.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from stillcap._checks import as_array
from stillcap.ball.flashes import number_flashes_from_hand
from stillcap.ball.release import estimate_release
from stillcap.body.hand import HAND_COLORS, fit_hand
from stillcap.body.hand_checks import hand_self_checks
from stillcap.body.hand_label import (GATE_M, TRIANGLE_TOL_M, HandLabels, contradicted_labels, label_hand_markers,
                                     unlabel_points)
from stillcap.body.hand_label_fill import (LEFTOVER_GATE_FACTOR, bone_offsets, digit_search, label_recovered,
                                          median_of_others, on_back_triangle, predicted_missing, root_fixed,
                                          whole_labels)
from stillcap.body.hand_track import HandSequence, dofs_on_partly_hidden, fit_hand_sequence, interpolate_animation
from stillcap.detect.color_markers import ColorBlobs, find_color_markers
from stillcap.io.capture import stereo_pairs
from stillcap.geometry.marker_near import triangulate_near
from stillcap.geometry.marker_points import MarkerPoints, _flux_ratios, triangulate_color_markers
from stillcap.pipelines.hand.ball import HandBalls, hand_ball_positions, hand_ball_spin
from stillcap.pipelines.hand.options import HandOptions

__all__ = ["HandSetup", "hand_setup", "read_hand_photos", "find_ball", "find_glove_markers", "triangulate_glove_markers", "label_markers", "recover_markers", "recover_near", "recover_digits", "fit_poses",
           "release_and_spin", "check_hand", "partly_hidden_angle_note", "label_markers_adapted",
           "marker_sigma", "misfit_residuals", "root_fixed", "testing_residuals"]

@dataclass
class HandSetup:
    """What a hand capture states before any photo is read: where it is (for messages), its
    stereo pairs (name -> cameras), the one strobe's rate, the strobe's position (or None) and
    the capture's messages so far."""

    where: str
    pairs: dict
    strobe_hz: float
    light: np.ndarray | None
    messages: list


def hand_setup(cap, strobe_position_m=None) -> HandSetup:
    """Check that ``cap`` is a hand capture lit by one strobe; ``ValueError`` names the capture."""
    where = f"capture {cap.root}" if cap.root is not None else "capture"
    if cap.kind != "hand":
        raise ValueError(f"{where} is a {cap.kind!r} capture, not a hand capture (capture.json \"kind\")")
    specs, messages = stereo_pairs(cap)
    rates = {sp.strobe_hz for sp in specs}
    if len(rates) != 1:
        raise ValueError(f"{where}: the stereo pairs have different strobe rates {sorted(rates)} Hz; "
                         "a hand capture is lit by one strobe")
    light = strobe_position_m if strobe_position_m is not None else cap.meta.get("strobe_position_m")
    if light is not None:
        light = as_array(light, (3,), "strobe_position_m")
    return HandSetup(where, {sp.name: sp.cameras for sp in specs}, rates.pop(), light, messages)


def read_hand_photos(cap, pairs: dict) -> list:
    """One photo per rig camera (None for a camera no stereo pair uses or with no photo)."""
    used = {c for cams in pairs.values() for c in cams}
    images = []
    for name in cap.rig.names:
        ims = cap.images_of(name)
        images.append(cap.read_image(ims[0]) if (name in used and ims) else None)
    return images


#: Position uncertainty of fully seen and of partly hidden glove markers (m), as measured by
#: ``benchmarks/bench_hand_markers.py`` (0.16 mm RMS and a few mm): the pose fit's weights.
SEEN_SIGMA_M, HIDDEN_SIGMA_M = 0.0003, 0.003


def find_ball(rig, images, strobe_hz: float, options: HandOptions, messages: list) -> HandBalls | None:
    """Stage 1: the ball's positions (None when it cannot be found: the reason in ``messages``)."""
    balls = None
    try:
        # every two cameras, not only the stereo pairs: fingers often hide the first free ball
        # from one camera of each pair (docs/hand-ball.md)
        balls = hand_ball_positions(rig, "all", images=images, ball_radius_m=options.ball_radius_m,
                                    strobe_hz=strobe_hz)
        messages.extend(balls.messages)
    except ValueError as e:
        messages.append(f"ball: {e}")
    return balls


def find_glove_markers(images, balls: HandBalls | None, rig=None) -> list:
    """Stage 2: the coloured blobs of every camera (empty where a camera has no photo), in linear
    light through each camera's response (``rig``; sRGB without one)."""
    blobs = []
    for i, img in enumerate(images):
        if img is None:
            blobs.append(ColorBlobs.empty())
            continue
        exclude = balls.ball_discs_px(i) if balls is not None and len(balls) else None
        blobs.append(find_color_markers(img, HAND_COLORS, exclude=exclude,
                                        encoding="srgb" if rig is None else rig[i].response))
    return blobs


def triangulate_glove_markers(rig, pairs: dict, blobs: list, light, options: HandOptions, messages: list,
                              where: str = "capture") -> MarkerPoints:
    """Stage 3: the unlabelled 3D markers of all flashes.

    Raises
    ------
    ValueError
        No glove marker seen by both cameras of a pair.
    """
    points = triangulate_color_markers(rig, pairs, blobs, light_position=light, radius_m=options.marker_radius_m)
    doubtful = points.partly_hidden & points.ambiguous
    if doubtful.any():
        # a partly hidden blob whose match no third view confirmed: on the benchmark these are
        # the points that get wrong labels; one view less is cheaper than a wrong label
        messages.append(f"{int(doubtful.sum())} partly hidden, unconfirmed 3D marker(s) left out")
        points = points.select(~doubtful)
    if len(points) == 0:
        raise ValueError(f"{where}: no glove marker seen by both cameras of a pair "
                         f"(blobs per camera: {dict(zip(rig.names, (len(b) for b in blobs)))})")
    return points


def _unconfirmed(points: MarkerPoints) -> np.ndarray:
    """Partly hidden points of two views: no third view checked their match, so a label needs a
    second labelled marker on its digit to be tested (label_hand_markers' ``unconfirmed``)."""
    return points.partly_hidden & (points.n_views == 2)


def marker_sigma(points: MarkerPoints, seen_m: float = SEEN_SIGMA_M) -> np.ndarray:
    """Each 3D marker's position noise (m) from what the photos show: ``seen_m`` for a fully seen
    marker, :data:`HIDDEN_SIGMA_M` for a partly hidden one (its centroid shifts by up to a few mm,
    docs/hand-markers.md) divided by the share of its light the worst view got (flux ratio: 1
    unhidden, 0.01 a sliver; clipped to 0.02-1)."""
    flux = np.where(np.isfinite(points.flux_ratio), points.flux_ratio, np.inf).min(axis=0)
    flux = np.clip(np.where(np.isfinite(flux), flux, 1.0), 0.02, 1.0)
    return np.where(points.partly_hidden, HIDDEN_SIGMA_M / flux, seen_m)


def label_markers(points: MarkerPoints, strobe_hz: float, options: HandOptions, messages: list, skeleton=None,
                  markerset=None) -> HandLabels:
    """Stage 4: the 3D markers labelled per flash with the hand model ``skeleton`` and ``markerset``
    (default the built-in ones; manual overrides from ``options.overrides``)."""
    labels = label_hand_markers(points.points, points.colors, strobe_hz=strobe_hz, skeleton=skeleton,
                                markerset=markerset, reprojection_px=points.reprojection_px,
                                overrides=options.overrides, unconfirmed=_unconfirmed(points))
    for k, why in enumerate(labels.skipped):
        if why:
            messages.append(f"flash {int(labels.order[k])}: no pose ({why})")
    return labels


def label_markers_adapted(points: MarkerPoints, strobe_hz: float, options: HandOptions, messages: list,
                          skeleton=None, markerset=None) -> tuple[HandLabels, bool]:
    """Stage 4 with ``--adapt-model`` (experimental): ``(labels, adapted)``, the markers labelled
    with the model adapted to this capture (:func:`stillcap.body.hand_adapt.label_and_adapt`)."""
    from stillcap.body.hand import hand_markerset, hand_skeleton
    from stillcap.body.hand_adapt import label_and_adapt

    labels, adaptation = label_and_adapt(points.points, points.colors, strobe_hz=strobe_hz,
                                         skeleton=skeleton or hand_skeleton(), markerset=markerset or hand_markerset(),
                                         reprojection_px=points.reprojection_px, overrides=options.overrides,
                                         unconfirmed=_unconfirmed(points))
    if adaptation is None:
        messages.append("--adapt-model: no flash with a pose to adapt the model to; the model was not adapted")
    for k, why in enumerate(labels.skipped):
        if why:
            messages.append(f"flash {int(labels.order[k])}: no pose ({why})")
    return labels, adaptation is not None


def blobs_over_ball(images, balls: HandBalls | None, blobs: list, rig=None) -> list:
    """Per camera, the glove blobs that the ball's discs masked out (stage 2 masks them so that
    the ball's painted markers are not taken): fingers in front of the ball in the image. Blobs of
    the photo found without the mask whose centre lies on a ball disc and that no blob of stage 2
    of the same colour explains (within the blob's own radius). Only the markers a posed hand
    predicts are looked for among them, and a point on the ball's surface is not taken
    (:func:`recover_markers`)."""
    out = []
    for i, img in enumerate(images):
        if img is None or balls is None or not len(balls) or not len(balls.ball_discs_px(i)[1]):
            out.append(ColorBlobs.empty(list(HAND_COLORS)))
            continue
        c, r = balls.ball_discs_px(i)
        free = find_color_markers(img, HAND_COLORS, encoding="srgb" if rig is None else rig[i].response)
        on = np.any(np.linalg.norm(free.centers[:, None] - c[None], axis=2) < r[None] + 1.0, axis=1)
        have = blobs[i]
        own = np.sqrt(np.maximum(free.areas, 1) / np.pi) + 1.0
        for j in np.flatnonzero(on):
            same = np.asarray(have.colors, object) == free.colors[j]
            if same.any() and np.min(np.linalg.norm(have.centers[same] - free.centers[j], axis=1)) <= own[j]:
                on[j] = False
        out.append(free.select(on))
    return out


def _joined(a: ColorBlobs, b: ColorBlobs) -> ColorBlobs:
    """The blobs of ``a`` then those of ``b`` (``b``'s index ``j`` becomes ``len(a) + j``)."""
    if not len(b):
        return a
    return ColorBlobs(np.concatenate([a.centers, b.centers]), list(a.colors) + list(b.colors),
                      np.concatenate([a.areas, b.areas]), np.concatenate([a.mean_hsb, b.mean_hsb]),
                      np.concatenate([a.flags, b.flags]), np.concatenate([a.roundness, b.roundness]),
                      np.concatenate([a.flux, b.flux]), list(a.color_names or b.color_names))


def recover_markers(rig, blobs: list, points: MarkerPoints, labels: HandLabels, light, options: HandOptions,
                    messages: list, images=None, balls: HandBalls | None = None, pairs: dict | None = None
                    ) -> tuple[list, MarkerPoints, HandLabels]:
    """Stage 4b: :func:`recover_near` (the markers looked for where the posed hands put them),
    then, with ``pairs``, :func:`recover_digits` (the digits whose pose is a guess searched over
    their range of motion). ``(blobs, points, labels)``."""
    n_own = [len(b) for b in blobs]  # recover_near may append the blobs on the ball's discs
    blobs, points, labels = recover_near(rig, blobs, points, labels, light, options, messages, images, balls)
    if pairs is not None:
        points, labels = recover_digits(rig, pairs, blobs, points, labels, light, options, messages, balls=balls,
                                        n_own=n_own)
    return blobs, points, labels


def recover_near(rig, blobs: list, points: MarkerPoints, labels: HandLabels, light, options: HandOptions,
                 messages: list, images=None, balls: HandBalls | None = None
                 ) -> tuple[list, MarkerPoints, HandLabels]:
    """Stage 4b, first part: ``(blobs, points, labels)`` with the markers the posed hands predict looked for
    again (issue 12): the blobs of the marker's colour near its prediction in every camera,
    combined and triangulated (:func:`~stillcap.geometry.marker_near.triangulate_near`), labelled
    only when the labeller's tests pass (:func:`~stillcap.body.hand_label_fill.label_recovered`).
    A point found so replaces the unlabelled point whose blobs it shares, else it is added. With
    ``images`` and ``balls``, the glove blobs the ball's discs masked out are looked among too
    (:func:`blobs_over_ball`, appended to ``blobs``); a point they give that lies on the ball
    (nearer its centre than its radius plus half a marker's) is the ball's paint, not taken."""
    flash, marker, pred = predicted_missing(labels)
    blobs_in = blobs
    if not len(flash):
        return blobs, points, labels
    if images is not None and balls is not None and len(balls):
        extra = blobs_over_ball(images, balls, blobs, rig)
        n_own = [len(b) for b in blobs]
        blobs = [_joined(b, e) for b, e in zip(blobs, extra)]
    else:
        n_own = None
    nc = len(rig.names)
    labelled = np.unique(labels.point_index[labels.point_index >= 0])
    # blobs of labelled points are taken; those of points a manual override deleted stay deleted
    taken = np.union1d(labelled, np.asarray(labels.deleted, int))
    used = [set(points.blob_index[c, taken][points.blob_index[c, taken] >= 0].tolist()) for c in range(nc)]
    gate = GATE_M * labels.hand_scale
    colours = np.asarray(labels.marker_colors)[marker]
    new, idx = triangulate_near(rig, blobs, pred, colours, LEFTOVER_GATE_FACTOR * gate, used=used, light_position=light,
                                radius_m=options.marker_radius_m, reference=points)
    if n_own is not None and len(new):
        extra_used = np.any(new.blob_index >= np.array(n_own)[:, None], axis=0)
        d_ball = np.min(np.linalg.norm(new.points[:, None] - balls.positions[None], axis=2), axis=1)
        paint = extra_used & (d_ball < options.ball_radius_m + 0.5 * options.marker_radius_m)
        new, idx = new.select(~paint), idx[~paint]
    if not len(new):
        return blobs_in, points, labels
    # a blob two new points want is no one's; a point whose blobs an unlabelled point shares
    # takes its row (one blob, one marker), with two such points it is left out
    nb = new.blob_index
    shared = np.array([any(np.any((nb[:, i] >= 0) & (nb[:, i] == nb[:, j])) for j in range(len(new)) if j != i)
                       for i in range(len(new))], bool)
    rows, keep = [], []
    for i in np.flatnonzero(~shared):
        over = np.flatnonzero(np.any((nb[:, i:i + 1] >= 0) & (points.blob_index == nb[:, i:i + 1]), axis=0))
        if len(over) > 1 or np.isin(over, taken).any():
            continue
        rows.append(int(over[0]) if len(over) else -1)
        keep.append(i)
    if not keep:
        return blobs_in, points, labels
    before = int((labels.point_index >= 0).sum())
    for _ in range(3):  # the points that got no label are left as they were, and the rest labelled again
        combined, at = _put_points(points, new.select(np.array(keep, int)), rows)
        proposals = [(p, int(flash[idx[i]]), int(marker[idx[i]])) for p, i in zip(at, keep)]
        # a back-of-hand point at the capture's own back-triangle sides from its flash's other
        # back-of-hand points is confirmed as a third view would confirm it (on_back_triangle)
        confirmed = combined.n_views >= 3
        on_back = on_back_triangle(labels, combined.points, proposals, unconfirmed=_unconfirmed(combined),
                                   tol_m=TRIANGLE_TOL_M * labels.hand_scale)
        confirmed[[p for (p, _, _), ok in zip(proposals, on_back) if ok]] = True
        out = label_recovered(labels, combined.points, combined.colors, proposals, gate_m=gate,
                              predicted=pred[idx[keep]], confirmed=confirmed, unconfirmed=_unconfirmed(combined))
        got = [bool(np.any(out.point_index == p)) for p in at]
        if all(got) or not any(got):
            break
        rows, keep = [r for r, g in zip(rows, got) if g], [i for i, g in zip(keep, got) if g]
    if not any(got):
        return blobs_in, points, labels
    labels = out
    added = int((labels.point_index >= 0).sum()) - before
    if added:
        messages.append(f"{added} marker(s) labelled where the posed hand predicted them (found again from "
                        f"their blobs)")
    return blobs, combined, labels


#: A view whose blob holds more than this many times the light the lit-sphere model predicts for
#: one marker is not one whole marker (:func:`recover_digits`).
MAX_FLUX_RATIO = 2.0


def recover_digits(rig, pairs: dict, blobs: list, points: MarkerPoints, labels: HandLabels, light,
                   options: HandOptions, messages: list, balls: HandBalls | None = None,
                   n_own=None) -> tuple[MarkerPoints, HandLabels]:
    """Stage 4b, second part: ``(points, labels)`` with the markers of digits whose fitted pose is
    a guess found and labelled (issue 12).

    On the studio's other hands most markers seen by two cameras that still had no label after
    :func:`recover_near` had clean blobs (epipolar distance 0.1-1 px) but no 3D point, on a digit
    with no other label, so its predicted markers lay 30-130 mm off. Two steps:

    1. the blobs no labelled point uses are matched again blind
       (:func:`~stillcap.geometry.marker_points.triangulate_color_markers`): without the labelled
       markers' blobs, a match that a rival blob on the same epipolar line made ambiguous may
       have one explanation left (partly hidden ambiguous points are left out as in stage 3);
    2. each posed flash's digits are searched over their range of motion among these points
       (:func:`~stillcap.body.hand_label_fill.digit_search`: two markers or more of one digit
       agreeing with one pose), and the proposals pass the labeller's tests
       (:func:`~stillcap.body.hand_label_fill.label_recovered`).

    A new point replaces the unlabelled point whose blobs it shares (two such points: left out).
    With ``balls`` and ``n_own`` (per camera, the blobs of stage 2; those after them are the
    blobs on the ball's discs that :func:`recover_near` appended), a point from a blob on a
    ball's disc that lies on the ball is the ball's paint, not taken (as in :func:`recover_near`).
    """
    from stillcap.body.hand_label import GRID_GATE_M, GRID_STEP_DEG

    if not labels.reconstructed.any():
        return points, labels
    nc = len(rig.names)
    cams = list(rig.cameras)
    r = options.marker_radius_m
    labelled = np.unique(labels.point_index[labels.point_index >= 0])
    # the blobs of points a manual override deleted stay deleted
    gone = np.union1d(labelled, np.asarray(labels.deleted, int))
    max_epi = 3.0 * max(c.image_size[0] for c in cams) / 1280.0  # the blind matching's tolerance
    keep = []
    for c, cam in enumerate(cams):
        mine = points.blob_index[c, gone]
        taken = set(mine[mine >= 0].tolist())
        b = blobs[c]
        if len(b) and len(labelled):
            # a blob where a labelled marker projects (a view its triangulation did not use, e.g.
            # partly hidden) is that marker's, not a free blob for a new match (a chance match of
            # such a blob gave the wrong labels of a first try)
            X = points.points[labelled]
            uv, z = cam.project(X), cam.world_to_cam(X)[:, 2]
            reach = cam.K[0, 0] * r / np.maximum(z, 1e-6) + max_epi
            d = np.linalg.norm(b.centers[:, None] - uv[None], axis=2)
            same = np.asarray(b.colors, object)[:, None] == np.asarray(points.colors[labelled], object)[None]
            taken |= set(np.flatnonzero(np.any(same & (d <= reach[None]) & (z[None] > 0), axis=1)).tolist())
        keep.append(np.array([i for i in range(len(b)) if i not in taken], int))
    left = [b.select(k) for b, k in zip(blobs, keep)]
    try:
        new = triangulate_color_markers(rig, pairs, left, light_position=light, radius_m=r)
    except ValueError:
        return points, labels
    if not len(new):
        return points, labels
    bi = new.blob_index.copy()  # back to the indices of ``blobs``
    for c in range(nc):
        has = bi[c] >= 0
        bi[c, has] = keep[c][bi[c, has]]
    if light is not None and len(points):
        # flux ratios normalised over the capture's points and these together (over the left-over
        # points alone, mostly partly hidden ones, a partly hidden view would look whole)
        flux = [np.asarray(b.flux, float) if len(b) else np.zeros(0) for b in blobs]
        allX = np.concatenate([points.points, new.points])
        allc = np.concatenate([np.asarray(points.colors).astype(str), np.asarray(new.colors).astype(str)])
        ratio = _flux_ratios(cams, allX, np.concatenate([points.blob_index, bi], axis=1), flux, allc, r,
                             np.asarray(light, float))[:, len(points):]
        new = replace(new, blob_index=bi, flux_ratio=np.where(bi >= 0, ratio, np.nan))
    else:
        new = replace(new, blob_index=bi)
    # as stage 3 leaves them out; and a view with twice the light of one whole marker is not one
    # marker (two merged, or a reflection): of the labelled points' views on the studio's other
    # hands 99.9 % held at most 1.32 times the model's light, the most 1.63; a point with a view
    # of 2.4 gave a wrong label of a first try
    bright = np.any(np.nan_to_num(new.flux_ratio, nan=1.0) > MAX_FLUX_RATIO, axis=0)
    paint = np.zeros(len(new), bool)
    if n_own is not None and balls is not None and len(balls):
        on_disc = np.any(new.blob_index >= np.array(n_own)[:, None], axis=0)
        d_ball = np.min(np.linalg.norm(new.points[:, None] - balls.positions[None], axis=2), axis=1)
        paint = on_disc & (d_ball < options.ball_radius_m + 0.5 * r)
    new = new.select(~(new.partly_hidden & new.ambiguous) & ~bright & ~paint)
    if not len(new):
        return points, labels
    # a new point takes the row of the one unlabelled point whose blobs it shares; with two such
    # points, or the same blobs as another new point, it is left out
    rows, sel = [], []
    for i in range(len(new)):
        over = np.flatnonzero(np.any((bi[:, i:i + 1] >= 0) & (points.blob_index == bi[:, i:i + 1]), axis=0))
        if len(over) > 1:
            continue
        rows.append(int(over[0]) if len(over) else -1)
        sel.append(i)
    taken_rows = [r for r in rows if r >= 0]
    dup = {r for r in taken_rows if taken_rows.count(r) > 1}
    pick = [(r, i) for r, i in zip(rows, sel) if r not in dup]
    if not pick:
        return points, labels
    rows, sel = [r for r, _ in pick], [i for _, i in pick]
    combined, at = _put_points(points, new.select(np.array(sel, int)), rows)
    scale = labels.hand_scale
    proposals, pred = digit_search(labels, combined.points, combined.colors, at, grid_gate_m=GRID_GATE_M * scale,
                                   gate_m=GATE_M * scale, grid_step_deg=GRID_STEP_DEG)
    if not proposals:
        return points, labels
    # only the points proposed are put in (the others stay as they were), and of those only the
    # ones the labeller's tests keep (a few rounds, as in recover_near)
    where = {p: j for j, p in enumerate(at)}
    props = [(where[p], k, m, x) for (p, k, m), x in zip(proposals, pred)]
    before = int((labels.point_index >= 0).sum())
    out = None
    for _ in range(3):
        use = sorted({j for j, _, _, _ in props})
        combined, at2 = _put_points(points, new.select(np.array([sel[j] for j in use], int)), [rows[j] for j in use])
        row_of = dict(zip(use, at2))
        out = label_recovered(labels, combined.points, combined.colors, [(row_of[j], k, m) for j, k, m, _ in props],
                              gate_m=GATE_M * scale, predicted=np.array([x for _, _, _, x in props]),
                              confirmed=combined.n_views >= 3, unconfirmed=_unconfirmed(combined))
        got = {j for j in use if np.any(out.point_index == row_of[j])}
        if got == set(use) or not got:
            break
        props = [q for q in props if q[0] in got]
    added = int((out.point_index >= 0).sum()) - before
    if added <= 0:
        return points, labels
    messages.append(f"{added} marker(s) labelled on digits searched over their range of motion (their blobs "
                    "matched again without the labelled markers' blobs)")
    return combined, out


def _put_points(points: MarkerPoints, new: MarkerPoints, rows) -> tuple[MarkerPoints, list]:
    """``points`` with ``new``'s point ``i`` in row ``rows[i]`` (replacing it) or appended (-1);
    also the row of each new point."""
    import dataclasses

    out = {f.name: getattr(points, f.name) for f in dataclasses.fields(MarkerPoints)}
    out = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    out["colors"] = out["colors"].astype(object)
    out["pairs"] = out["pairs"].astype(object)
    at = []
    for i, r in enumerate(rows):
        if r < 0:
            r = len(out["points"])
            for key, axis in (("points", 0), ("colors", 0), ("n_views", 0), ("reprojection_px", 0), ("pixels", 1),
                              ("blob_index", 1), ("pairs", 0), ("ambiguous", 0), ("flux_ratio", 1)):
                v = getattr(new, key)
                out[key] = np.concatenate([out[key], np.take(v, [i], axis=axis)], axis=axis)
        else:
            for key in ("points", "colors", "n_views", "reprojection_px", "pairs", "ambiguous"):
                out[key][r] = getattr(new, key)[i]
            for key in ("pixels", "blob_index", "flux_ratio"):
                out[key][:, r] = getattr(new, key)[:, i]
        at.append(r)
    out["colors"] = out["colors"].astype(str)
    out["pairs"] = out["pairs"].astype(str)
    return MarkerPoints(**out), at


def _labelled(labels: HandLabels, flashes) -> np.ndarray:
    """The labelled points of ``flashes`` (shape (n, n_markers, 3), NaN where unlabelled)."""
    pi = labels.point_index[np.asarray(flashes, int)]
    return np.where((pi >= 0)[..., None], labels.points[np.maximum(pi, 0)], np.nan)


def misfit_residuals(labels: HandLabels, sequence: HandSequence, unconfirmed) -> np.ndarray:
    """The fit's residuals (shape (n, n_markers), m; NaN where unlabelled) with each marker's own
    misfit removed: a model of other proportions misses a marker the same way in every flash, in
    the frame of its bone, so a marker's residual is measured from the fitted marker moved by its
    median offset over the other flashes where a point that is not ``unconfirmed`` (bool per
    point) carries its label (:func:`~stillcap.body.hand_label_fill.median_of_others`, as
    :func:`~stillcap.body.hand_label_fill.predicted_missing` says). Without such a flash the
    residual is the plain distance. Studio hand 11 with the built-in model: whole ``index.pip``
    points sit 6.9-7.7 mm from the fitted model in three flashes, so a partly hidden
    ``index.pip`` 1 mm from its truth sat 8.4 mm off and lost its right label."""
    offs, med = _offsets_and_median(labels, sequence, unconfirmed)
    out = np.array(sequence.residuals, float)
    moved = np.isfinite(offs[..., 0]) & np.isfinite(med[..., 0])
    out[moved] = np.linalg.norm(offs[moved] - med[moved], axis=1)
    return out


def _offsets_and_median(labels: HandLabels, sequence: HandSequence, unconfirmed):
    """The labelled markers' bone-frame offsets from ``sequence``'s fit and, per flash, their
    median over the other flashes' whole labels (both shape (n, n_markers, 3))."""
    offs = bone_offsets(sequence.skeleton, sequence.markerset, sequence.poses, _labelled(labels, sequence.flashes))
    return offs, median_of_others(offs, whole_labels(labels, sequence.flashes, unconfirmed))


def testing_residuals(labels: HandLabels, sequence: HandSequence, unconfirmed) -> np.ndarray:
    """The residuals that test the unconfirmed labels (:func:`fit_poses`), as
    :func:`misfit_residuals` gives them for ``sequence`` (each point at its own noise, so
    partly hidden points count little), except in flashes whose root no whole back-of-hand
    triplet fixes (:func:`root_fixed`). There the whole markers leave the root free and the
    weighted fit's root floats (studio hand 12 with the built-in model, its flash 0 posed from
    its neighbours: the fitted back.2/back.3 9-10 mm off the truth, a right ``index.pip`` 1 mm
    from its truth left 12.6 mm off). In such a flash an unconfirmed label of marker ``m`` is
    tested by the flash fitted without it, every other point weighted alike (as the labeller
    fitted it; the point left out, so the fit cannot bend to it), from the weighted fit's pose;
    its residual is measured from the marker so predicted moved by the median bone-frame offset
    of ``m``'s whole points from their own predictions made the same way (each of those flashes
    fitted without its ``m``): how far the model predicts a marker it is not given, on this hand."""
    unconfirmed = np.asarray(unconfirmed, bool)
    out = misfit_residuals(labels, sequence, unconfirmed)
    free = np.flatnonzero(~root_fixed(labels, sequence.flashes, unconfirmed))
    if not len(free):
        return out
    sk, ms = sequence.skeleton, sequence.markerset
    pos = _labelled(labels, sequence.flashes)
    pi = labels.point_index[np.asarray(sequence.flashes, int)]
    whole = whole_labels(labels, sequence.flashes, unconfirmed)
    left_out = {}

    def offset_without(i, m):  # marker m's bone-frame offset from the fit of flash i without it
        if (i, m) not in left_out:
            left = pos[i].copy()
            left[m] = np.nan
            pose = fit_hand(sk, ms, left, initial=sequence.poses[i]).pose
            left_out[i, m] = bone_offsets(sk, ms, [pose], pos[i][None])[0, m]
        return left_out[i, m]

    for i in free:
        for m in np.flatnonzero((pi[i] >= 0) & ~whole[i]):
            others = [offset_without(j, m) for j in np.flatnonzero(whole[:, m]) if j != i]
            med = np.median(others, axis=0) if others else 0.0
            out[i, m] = np.linalg.norm(offset_without(i, m) - med)
    return out


def fit_poses(labels: HandLabels, points: MarkerPoints, options: HandOptions, messages: list):
    """Stage 5: ``(labels, sequence, animation)``, the hand poses of the flashes with the three
    back-of-hand markers and the animation through them (None where there are too few); the
    labels without those the fit contradicts (:func:`~stillcap.body.hand_label.contradicted_labels`)."""
    sequence = animation = None
    if labels.reconstructed.any():
        # partly hidden markers' centroids shift by up to a few mm (docs/hand-markers.md): they
        # count 10x less in the pose fit than fully seen ones, and less still the less of their
        # light a view got (flux ratio: 1 unhidden, 0.01 a sliver)
        sigma = marker_sigma(points)
        sequence = fit_hand_sequence(labels, personalise=options.personalise, times=labels.times,
                                     point_sigma_m=sigma)
        # a partly hidden point of two views that this fit (each point at its own noise) leaves
        # beyond the labelling gate is not the marker its label names: unlabelled, fitted again
        unconfirmed = _unconfirmed(points)
        far = contradicted_labels(labels, testing_residuals(labels, sequence, unconfirmed), sequence.flashes,
                                  unconfirmed)
        if len(far):
            messages.append(f"{len(far)} partly hidden 3D marker(s) unlabelled: farther from the fitted hand "
                            f"than the labelling gate")
            labels = unlabel_points(labels, far)
            sequence = fit_hand_sequence(labels, personalise=options.personalise, times=labels.times,
                                         point_sigma_m=sigma)
        if sequence.n >= 2:
            animation = interpolate_animation(sequence, options.frame_rate, method=options.interpolation)
        else:
            messages.append("one pose only: no animation")
    else:
        messages.append("no flash shows the three back-of-hand markers: no hand pose")
    return labels, sequence, animation


def release_and_spin(rig, balls: HandBalls | None, sequence: HandSequence | None, strobe_hz: float, pairs: dict,
                     images, options: HandOptions, messages: list):
    """Stage 6: ``(balls, release, spin)``: the ball's flashes renumbered on the hand's clock, the
    release and the free ball's spin (None where they cannot be had)."""
    release = spin = None
    if balls is not None and len(balls) and sequence is not None:
        hold_times = sequence.times
        r2w = sequence.root2world
        balls = _on_hand_clock(balls, hold_times, r2w, strobe_hz, messages)
        release = estimate_release(balls.times, balls.positions, hold_times, r2w, strobe_hz=strobe_hz,
                                   position_sigma_m=balls.sigma_m)
        if release.message:
            messages.append(f"release: {release.message}")
        if options.spin and release.success:
            spin = hand_ball_spin(rig, balls, ~release.held, pairs=pairs, images=images)
            if spin.message:
                messages.append(f"spin: {spin.message}")
    return balls, release, spin


def _on_hand_clock(balls: HandBalls, hold_times, root2world, strobe_hz: float, messages: list) -> HandBalls:
    """Renumber the ball's flashes from the hand poses (:func:`stillcap.ball.flashes.number_flashes_from_hand`):
    the ball was found before the hand (its discs mask the glove-marker search), numbered from
    its spacing, which a missed flash of an accelerating arm gets wrong."""
    fn = number_flashes_from_hand(balls.positions, hold_times, root2world, strobe_hz=strobe_hz)
    if not fn.success:
        messages.append(f"ball: {fn.message}; flashes numbered from the ball's spacing")
        return balls
    return replace(balls, flash_index=np.asarray(fn.flash, int), times=np.asarray(fn.times, float))


def check_hand(labels: HandLabels, sequence: HandSequence | None, points: MarkerPoints, adapted: bool = False,
               messages: list | None = None) -> list:
    """Stage 7: the self-checks (:func:`~stillcap.body.hand_checks.hand_self_checks`), fully seen
    markers against :data:`SEEN_SIGMA_M`, partly hidden ones against :data:`HIDDEN_SIGMA_M`; the
    note on angles that rest only on partly hidden markers (:func:`partly_hidden_angle_note`) is
    added to ``messages``."""
    checks = hand_self_checks(labels, sequence, partly_hidden=points.partly_hidden, noise_m=SEEN_SIGMA_M,
                              hidden_noise_m=HIDDEN_SIGMA_M, adapted=adapted)
    note = partly_hidden_angle_note(labels, sequence, points)
    if note and messages is not None:
        messages.append(note)
    return checks


def partly_hidden_angle_note(labels: HandLabels, sequence: HandSequence | None, points: MarkerPoints) -> str | None:
    """A note naming the joint angles that rest only on partly hidden markers
    (:func:`~stillcap.body.hand_track.dofs_on_partly_hidden`), or None: the markers fix them, but a
    partly hidden marker's centroid shifts by up to a few mm, so the angle is less sure than those
    fully seen markers fix (on the studio's other hands 1-12, with the hand's own model 1.5-4.1 deg
    RMS against 0.3-1.0 deg; ``joint_angle_rms_partly_hidden_deg``). A note, not a failed
    self-check: the ball hides part of some finger in nearly every throw (the studio's own demo
    among them), so it says what an angle rests on, not that the photos disagree with the model.
    The JSON lists the angles per flash (``flashes.angles_partly_hidden``) and the terminal's
    joint-angle table marks them."""
    if sequence is None or not sequence.n:
        return None
    flag = dofs_on_partly_hidden(sequence, labels.point_index, points.partly_hidden)
    if not flag.any():
        return None
    sk = sequence.skeleton
    joints = ", ".join(sk.names[j] for j in np.flatnonzero(flag.any(axis=(0, 2))))
    n_poses = int(flag.any(axis=(1, 2)).sum())
    return (f"{int(flag.sum())} joint angle(s) in {n_poses} of {sequence.n} poses rest only on partly hidden "
            f"markers (joints {joints}): their centroids shift by up to a few mm, so expect several degrees "
            "more error there (per flash in the JSON's flashes.angles_partly_hidden)")
