"""Automatic labelling of the glove's markers in one multi-exposure capture (SPEC J2, issue 5).

Input: unlabelled 3D marker points of all flashes mixed, ``points`` (N, 3) in the field frame
(metres) and their glove colour names ``colours`` (N,) (:data:`stillcap.body.hand.HAND_COLORS`).
Output: :class:`HandLabels`, the points grouped into flashes, ordered in time, each labelled with
a marker of the hand model (:func:`~stillcap.body.hand.hand_markerset`). See
``docs/hand-labelling.md``.

The method (:func:`label_hand_markers`):

1. **Back-of-hand triplets.** The three back markers (:data:`~stillcap.body.hand.BACK_MARKERS`)
   have three different colours and known mutual distances (a scalene triangle of 44, 52 and
   58 mm), so every triple of points with those colours and distances is a candidate hand, and
   the rigid alignment of the triangle gives its root pose.
2. **Per-digit grid search.** Given a root pose, each digit's three markers depend only on that
   digit's joint angles. A grid over the joint limits (15 degree steps, 3-10 thousand poses per
   digit, vectorised forward kinematics precomputed in the hand frame) is scored against the
   points of the right colours (squared distance to the nearest one, capped at a gate); the
   best grid pose per digit gives a tentative labelling and the candidate's score (markers
   matched). Candidates are accepted greedily, best first, each taking its points out of play.
3. **Time order.** The hands are sorted along the throw direction (the hand travels toward
   home plate, ``-y`` in the field frame, by 0.1-0.3 m between flashes of a 75 Hz strobe).
4. **Fit and optimal assignment.** In time order, each hand is fitted (:func:`fit_hand`, the
   previous flash's angles as a prior grid pose and start) and its labels re-assigned with
   :func:`scipy.optimize.linear_sum_assignment` on the squared distance between the model's
   markers and the points (a different colour is forbidden, a dummy column at the gate's cost
   lets a marker stay unseen), alternating until the labels no longer change. Points farther
   than the gate from every marker are left unassigned (spurious matches).
5. **Skipped flashes.** Points left over are clustered (single linkage); a cluster of a few
   points is a flash whose back-of-hand triplet was not found: it is reported with why, without
   a pose (the seed's rule).
6. **Filling in** (issue 12, :mod:`stillcap.body.hand_label_fill`): such a flash is posed from
   its other markers with a neighbouring flash's pose as the prior, keeping only the labels every
   competing hypothesis agrees on; then points the gate did not reach are labelled after the
   fits when exactly one marker of their colour lies within a wider gate (two candidates leave
   both unlabelled).
7. **False back-of-hand triplets** (issue 12): a triplet's hand that another posed flash's hand
   explains (its points on that hand's markers) and that does not explain it back, or one beside
   a larger flash left without a pose, is labelled again without (:func:`flashes_at_one_place`:
   flashes of one strobe sequence are at different places).

Manual corrections (:func:`read_label_overrides`, :func:`apply_label_overrides`) name a point
by its flash and 3D position (within a tolerance, so they survive re-runs) and relabel or
delete it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from pydantic import Field
from scipy.cluster.hierarchy import fcluster, linkage

from stillcap._checks import as_array, as_rng
from stillcap.body.hand import BACK_MARKERS, HAND_COLORS, fit_hand, hand_markerset, hand_skeleton
from stillcap.body.hand_grid import LabelModel, back_triplets, grid_match, label_flash, root_pose
from stillcap.body.hand_label_fill import MIN_SIDE_M, PAIR_TOL_M, label_leftovers, pose_from_neighbours
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton
from stillcap.files.jsonable import to_jsonable
from stillcap.files.jsonfile import read_json
from stillcap.files.schema import ClosedModel, Model, Name, PositiveCount, Vec3, validate

__all__ = ["HandLabels", "LabelOverride", "apply_label_overrides", "contradicted_labels", "explained_points",
           "flashes_at_one_place", "hand_points_from_truth", "label_hand_markers", "read_label_overrides", "unlabel_points"]

#: Tolerance on each side of the back-of-hand triangle (m): noise of both ends plus margin.
TRIANGLE_TOL_M = 0.006
#: Gate of the grid search (m): grid poses are 15 degrees apart, up to ~10 mm off at a nail.
GRID_GATE_M = 0.020
#: Gate of the final assignment (m): a point farther than this from its fitted marker is not it.
GATE_M = 0.008
#: Grid step of the per-digit search (degrees).
GRID_STEP_DEG = 15.0
#: Sizes relative to the model (lowest, highest) a hand may have: the back-of-hand triangle is
#: searched at any size in this range, and the model and every gate scale with the size found.
SIZE_RANGE = (0.75, 1.35)
#: A hand needs this many markers (its 3 back markers included) to count.
MIN_MARKERS = 6
#: Single-linkage distance (m) grouping left-over points into a skipped flash, and the points
#: such a group needs.
CLUSTER_LINK_M = 0.10
MIN_SKIPPED_POINTS = 4
#: Most false back-of-hand triplets rejected in one capture (each costs one more labelling run).
MAX_REJECTED_TRIPLETS = 4

_OVERRIDES_FORMAT = "stillcap-label-overrides"
_Tolerance = Field(None, strict=True, gt=0, le=1000, allow_inf_nan=False)


class OverrideEntry(ClosedModel):
    """One entry of a label overrides file's ``overrides``."""

    flash: int = Field(strict=True, ge=0)
    position_m: Vec3
    label: Name | None = None
    delete: bool = Field(False, strict=True)
    tolerance_mm: float | None = _Tolerance
    comment: Any = None


class OverridesFile(Model):
    """A label overrides file (``stillcap-label-overrides``, ``docs/hand-labelling.md``)."""

    format: Literal["stillcap-label-overrides"] = _OVERRIDES_FORMAT
    version: PositiveCount = 1
    tolerance_mm: float | None = _Tolerance
    overrides: list[OverrideEntry]


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------
@dataclass(eq=False)
class HandLabels:
    """Markers of one capture grouped into flashes, ordered in time and labelled.

    Flashes are in time order (first flash first). ``n`` flashes, ``m`` markers, ``N`` points.

    Attributes
    ----------
    marker_names, marker_colours : list of str
        The marker set's markers and their colours (length m).
    order : ndarray of int, shape (n,)
        Strobe period of each flash counted from the first flash found (0, 1, 2, ...).
    times : ndarray, shape (n,)
        ``order / strobe_hz``: seconds after the first flash found.
    strobe_hz : float
    point_index : ndarray of int, shape (n, m)
        The point labelled as each marker, -1 = none.
    positions : ndarray, shape (n, m, 3)
        The labelled points' positions (m); NaN = not seen.
    reconstructed : ndarray of bool, shape (n,)
        The flash has a fitted pose (:attr:`pose_source` says from what).
    skipped : list of str
        Why a flash has no pose ("" for reconstructed flashes).
    members : list of ndarray of int
        Points of each flash: its labelled points, and for a skipped flash the points of its
        cluster.
    unassigned : ndarray of int
        Points labelled in no flash (spurious points, points of skipped flashes, rejected ones).
    deleted : ndarray of int
        Points removed by manual overrides.
    rms : ndarray, shape (n,)
        RMS of the fit's marker residuals per flash (m); NaN for skipped flashes.
    fits : list of HandFit or None
        The hand fit per flash (None when skipped).
    points : ndarray, shape (N, 3)
    colours : ndarray of str, shape (N,)
    skeleton : Skeleton
    markerset : MarkerSet
        The hand the labels were made with (the model scaled to the hand's size).
    hand_scale : float
        The hand's size relative to the model given (estimated from its back-of-hand triangles
        unless given).
    pose_source : list of str
        How each flash got its pose: ``"triplet"`` (its back-of-hand triplet), ``"neighbours"``
        (its other markers with a neighbouring flash's pose as the prior,
        :func:`~stillcap.body.hand_label_fill.pose_from_neighbours`), ``"overrides"`` (refitted
        after manual overrides) or ``""`` (no pose).
    """

    marker_names: list
    marker_colors: list
    order: np.ndarray
    times: np.ndarray
    strobe_hz: float
    point_index: np.ndarray
    positions: np.ndarray
    reconstructed: np.ndarray
    skipped: list
    members: list
    unassigned: np.ndarray
    deleted: np.ndarray
    rms: np.ndarray
    fits: list
    points: np.ndarray
    colors: np.ndarray
    skeleton: Skeleton = field(repr=False)
    markerset: MarkerSet = field(repr=False)
    hand_scale: float = 1.0
    pose_source: list = field(default_factory=list)

    @property
    def n_flashes(self) -> int:
        return len(self.order)

    @property
    def root2world(self) -> np.ndarray:
        """Fitted root pose per flash, shape (n, 4, 4); NaN for skipped flashes."""
        out = np.full((self.n_flashes, 4, 4), np.nan)
        for k, f in enumerate(self.fits):
            if f is not None:
                out[k] = f.pose.root2world
        return out

    def labels(self) -> np.ndarray:
        """Per point ``(flash, marker)`` indices, shape (N, 2); ``(-1, -1)`` when unlabelled."""
        out = np.full((len(self.points), 2), -1, int)
        for k, row in enumerate(self.point_index):
            for j, p in enumerate(row):
                if p >= 0:
                    out[p] = (k, j)
        return out

    def to_dict(self) -> dict:
        """JSON-ready dict; keys shared with the hand truth (``flashes.markers``, ``times_s``,
        ``root2world``), NaN written as null."""
        return to_jsonable({
            "kind": "hand-labels", "frame": "field", "units": {"length": "m", "time": "s (since the first flash found)"},
            "strobe_hz": self.strobe_hz, "marker_names": list(self.marker_names),
            "marker_colours": list(self.marker_colors), "n_points": len(self.points),
            "flashes": {"order": self.order, "times_s": self.times, "point_index": self.point_index,
                        "markers": self.positions, "reconstructed": self.reconstructed,
                        "skipped": list(self.skipped), "rms_mm": self.rms * 1000, "root2world": self.root2world,
                        "members": [m.tolist() for m in self.members]},
            "unassigned": self.unassigned, "deleted": self.deleted, "hand_scale": self.hand_scale,
            "pose_source": list(self.pose_source),
        })


def _accept(model, pts, cols, usable, cands, sizes, grid_gate, min_markers, roots=None) -> list:
    """Candidate hands accepted greedily, best grid score first, each taking its points out of
    play; candidate ``i`` is the model scaled by ``sizes[i]``."""
    if roots is None:
        roots = [root_pose(model, pts, c, s) for c, s in zip(cands, sizes)]
    avail = usable.copy()
    accepted = []
    alive = np.ones(len(cands), bool)
    while alive.any():
        best, best_key, best_pts = -1, None, None
        for i in np.flatnonzero(alive):
            if not avail[cands[i]].all():
                alive[i] = False
                continue
            lab, _, n, cost = grid_match(model, roots[i], pts, cols, avail, grid_gate, scale=sizes[i])
            if n + 3 < min_markers:
                alive[i] = False
                continue
            key = (n, -cost)
            if best_key is None or key > best_key:
                best, best_key, best_pts = i, key, list(lab.values())
        if best < 0:
            break
        accepted.append(best)
        alive[best] = False
        avail[cands[best]] = False
        avail[best_pts] = False
    return accepted


def _check_inputs(points, colors, reprojection_px):
    pts = as_array(points, (None, 3), "points")
    cols = np.asarray(colors, dtype=object)
    if cols.shape != (len(pts),):
        raise ValueError(f"colours must have shape ({len(pts)},) like points, got {cols.shape}")
    bad = sorted({str(c) for c in cols} - set(HAND_COLORS))
    if bad:
        raise ValueError(f"colours must be names in {sorted(HAND_COLORS)}, got {bad}")
    rep = None
    if reprojection_px is not None:
        rep = as_array(reprojection_px, (len(pts),), "reprojection_px")
    return pts, cols.astype(str), rep


def label_hand_markers(points, colors, *, strobe_hz: float, skeleton: Skeleton | None = None,
                       markerset: MarkerSet | None = None, throw_direction=(0.0, -1.0, 0.0), reprojection_px=None,
                       max_reprojection_px: float | None = None, overrides=None, triangle_tol_m: float = TRIANGLE_TOL_M,
                       gate_m: float = GATE_M, grid_gate_m: float = GRID_GATE_M, grid_step_deg: float = GRID_STEP_DEG,
                       min_markers: int = MIN_MARKERS, hand_scale: float | None = None,
                       size_range=SIZE_RANGE, fill: bool = True, unconfirmed=None,
                       reject_false_triplets: bool = True, _rejected: frozenset = frozenset()) -> HandLabels:
    """Group unlabelled hand markers into flashes, order them in time and label them.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        Marker positions of all flashes mixed (field frame, metres); rows with NaN are ignored.
    colours : array_like of str, shape (N,)
        Each point's glove colour (a name of :data:`~stillcap.body.hand.HAND_COLORS`).
    strobe_hz : float
        The strobe; flash ``k`` in time order is at ``k / strobe_hz`` after the first.
    skeleton, markerset : optional
        The hand (default :func:`hand_skeleton`, :func:`hand_markerset`; a personalised hand
        labels a little better).
    throw_direction : array_like, shape (3,)
        Where the hand travels (default ``-y``, toward home plate): it orders the flashes.
    reprojection_px : array_like, shape (N,), optional
        Each point's reprojection error; with ``max_reprojection_px`` points above it are not used.
    max_reprojection_px : float, optional
    overrides : path, or sequence of LabelOverride, optional
        Manual corrections applied at the end (:func:`apply_label_overrides`).
    triangle_tol_m, gate_m, grid_gate_m, grid_step_deg, min_markers
        Tuning (module constants), in metres for a hand of the model's size: every gate is
        multiplied by the hand's size.
    hand_scale : float, optional
        The hand's size relative to the model; default: estimated from the back-of-hand
        triangles found (any size in ``size_range``). The model is scaled by it
        (:func:`~stillcap.body.hand.scale_hand`) and so are the gates; the result's skeleton
        and marker set are the scaled ones, and :attr:`HandLabels.hand_scale` says it.
    size_range : (float, float)
        Sizes relative to the model a hand may have (default :data:`SIZE_RANGE`).
    fill : bool
        Fill in labels the first pass leaves out (steps 6-7, :mod:`stillcap.body.hand_label_fill`):
        flashes without a back-of-hand triplet posed from their other markers and a neighbouring
        flash's pose, and points the gate did not reach labelled after the fits when only one
        marker can be theirs. False gives the first pass alone.
    unconfirmed : array_like of bool, shape (N,), optional
        Points that nothing but their own blobs supports (the hand pipeline: partly hidden and
        seen by two cameras, so no third view checked the match). Such a point keeps its label
        only beside another labelled marker of its digit: alone on a digit, the digit's joints
        bend to it and its residual is zero whatever it is, so nothing tests it (on studio
        hands 3 and 5, a sliver pair 17-21 mm from every marker took ``ring.dip``).
    reject_false_triplets : bool
        After filling in (step 8): a flash posed from a back-of-hand triplet whose points another
        posed flash's fitted hand explains (at least three of them on its markers), while it
        explains fewer of that flash's, is a false triplet (three finger markers of a flash whose
        back is unseen); the capture is labelled again without it (at most
        :data:`MAX_REJECTED_TRIPLETS`). False keeps such hands (the self-check
        ``flashes_at_one_place`` of :mod:`stillcap.body.hand_checks` still names them).

    Returns
    -------
    HandLabels
    """
    pts, cols, rep = _check_inputs(points, colors, reprojection_px)
    if unconfirmed is not None:
        unconfirmed = np.asarray(unconfirmed)
        if unconfirmed.shape != (len(pts),) or unconfirmed.dtype != bool:
            raise ValueError(f"unconfirmed must be {len(pts)} booleans (one per point), got "
                             f"{unconfirmed.dtype} of shape {unconfirmed.shape}")
    strobe_hz = float(strobe_hz)
    if not (np.isfinite(strobe_hz) and strobe_hz > 0):
        raise ValueError(f"strobe_hz must be finite and > 0, got {strobe_hz}")
    throw = as_array(throw_direction, (3,), "throw_direction")
    if not np.linalg.norm(throw) > 0:
        raise ValueError(f"throw_direction must be a non-zero vector, got {throw}")
    throw = throw / np.linalg.norm(throw)
    skeleton = skeleton or hand_skeleton()
    markerset = markerset or hand_markerset()
    model = LabelModel(skeleton, markerset, grid_step_deg)
    usable = np.all(np.isfinite(pts), axis=1)
    if rep is not None and max_reprojection_px is not None:
        usable &= ~(rep > float(max_reprojection_px))

    # 0. the hand's size: candidate triplets of any size in the range, accepted greedily by grid
    # score with the model scaled to each; the median size of the accepted hands scales the model
    # and every gate (a hand larger or smaller than the model is not lost to fixed mm gates)
    if hand_scale is None:
        cands, sizes = back_triplets(pts, cols, usable, model, triangle_tol_m, size_range)
        acc = _accept(model, pts, cols, usable, cands, sizes, grid_gate_m, min_markers)
        hand_scale = float(np.median(sizes[acc])) if len(acc) else 1.0
    hand_scale = float(hand_scale)
    if not (np.isfinite(hand_scale) and hand_scale > 0):
        raise ValueError(f"hand_scale must be a positive factor, got {hand_scale}")
    if hand_scale != 1.0:
        from stillcap.body.hand import scale_hand

        skeleton, markerset = scale_hand(skeleton, markerset, hand_scale)
        model = LabelModel(skeleton, markerset, grid_step_deg)
        triangle_tol_m, gate_m, grid_gate_m = (v * hand_scale for v in (triangle_tol_m, gate_m, grid_gate_m))

    # 1-2. candidate hands from back-of-hand triplets, accepted greedily by grid score
    cands, _ = back_triplets(pts, cols, usable, model, triangle_tol_m)
    cands = [c for c in cands if frozenset(int(x) for x in c) not in _rejected]
    roots = [root_pose(model, pts, c) for c in cands]
    accepted = _accept(model, pts, cols, usable, cands, np.ones(len(cands)), grid_gate_m, min_markers, roots)

    # 3. time order of the hands, by their points' centroid along the throw
    def centroid(i):
        lab, _, _, _ = grid_match(model, roots[i], pts, cols, usable, grid_gate_m)
        return np.mean(pts[list(lab.values()) + list(cands[i])], axis=0)

    hands = [(float(centroid(i) @ throw), i) for i in accepted]

    # 4. fit and label in time order, each flash starting from the previous one
    avail = usable.copy()
    results = {}
    prior = None
    for _, i in sorted(hands):
        if not avail[cands[i]].all():
            results[i] = None
            continue
        labels, fit, _ = label_flash(model, pts, cols, avail, cands[i], prior, grid_gate_m, gate_m)
        results[i] = (labels, fit)
        avail[list(labels.values())] = False
        prior = fit.angles_deg

    # 5. left-over points: clusters are flashes without a back-of-hand triplet
    flashes = []  # (position along the throw, labels or None, fit or None, members, reason)
    for s, i in hands:
        if results[i] is None:
            continue
        labels, fit = results[i]
        flashes.append((s, labels, fit, np.array(sorted(labels.values()), int), ""))
    left = np.flatnonzero(avail)
    if len(left) >= MIN_SKIPPED_POINTS:
        cl = fcluster(linkage(pts[left], "single"), CLUSTER_LINK_M, criterion="distance")
        for c in np.unique(cl):
            mem = left[cl == c]
            if len(mem) < MIN_SKIPPED_POINTS:
                continue
            found = sorted({str(x) for x in cols[mem]} & set(model.colors[model.back]))
            flashes.append((float(pts[mem].mean(axis=0) @ throw), None, None, mem,
                            f"no back-of-hand triplet ({', '.join(BACK_MARKERS)}: colours "
                            f"{', '.join(model.colors[model.back])} at the model's distances) among its "
                            f"{len(mem)} points (back colours present: {', '.join(found) or 'none'})"))
    flashes.sort(key=lambda f: f[0])
    source = ["triplet" if f[2] is not None else "" for f in flashes]

    # 6-7. flashes without a triplet posed from their other markers and a neighbour's pose; points
    # the gate did not reach labelled after the fits when only one marker can be theirs
    if fill:
        flashes = [list(f) for f in flashes]
        for k in pose_from_neighbours(model, pts, cols, flashes, grid_gate=grid_gate_m, gate=gate_m,
                                      min_markers=min_markers, pair_tol=PAIR_TOL_M * hand_scale,
                                      min_side=MIN_SIDE_M * hand_scale):
            source[k] = "neighbours"
        avail = usable.copy()
        for f in flashes:
            avail[list(f[1].values()) if f[1] else []] = False
            if f[2] is None:
                avail[f[3]] = False  # the points of a flash still without a pose stay its own
        label_leftovers(model, pts, cols, avail, flashes, gate=gate_m)

    n, m = len(flashes), len(markerset)
    point_index = np.full((n, m), -1, int)
    for k, (_, labels, _, _, _) in enumerate(flashes):
        for mk, p in (labels or {}).items():
            point_index[k, mk] = p
    if unconfirmed is not None:
        _drop_lone_unconfirmed(model, point_index, unconfirmed)
    out = _build(model, pts, cols, strobe_hz, point_index, [f[2] for f in flashes], [f[4] for f in flashes],
                 [f[3] for f in flashes], np.array([], int), hand_scale, source)

    # 8 (docs: step 11). false back-of-hand triplets (three finger markers of a flash whose back is unseen, at the
    # back's colours and distances: hand 11 of issue 12). A triplet's hand that another posed
    # flash's hand explains (its points lie on that hand's markers) while it does not explain that
    # flash back is a second hand at the place of its flash's real one: label again without it. A
    # triplet's hand beside a flash left without a pose that has more points than it labelled may
    # be one too: label again without it and keep whichever labelling labels more points.
    if fill and reject_false_triplets and len(_rejected) < MAX_REJECTED_TRIPLETS:
        false, suspect = _false_triplets(model, pts, cols, flashes, source, gate_m, CLUSTER_LINK_M * hand_scale)
        for bad, sure in ([(false, True)] if false else []) + [([t], False) for t in suspect]:
            # the model and gates are already scaled to the hand: the rerun keeps them as they are
            again = label_hand_markers(
                points, colors, strobe_hz=strobe_hz, skeleton=skeleton, markerset=markerset, throw_direction=throw,
                reprojection_px=reprojection_px, max_reprojection_px=max_reprojection_px,
                triangle_tol_m=triangle_tol_m, gate_m=gate_m, grid_gate_m=grid_gate_m, grid_step_deg=grid_step_deg,
                min_markers=min_markers, hand_scale=1.0, size_range=size_range, fill=fill, unconfirmed=unconfirmed,
                _rejected=_rejected | frozenset(bad))
            if sure or (again.point_index >= 0).sum() > (out.point_index >= 0).sum():
                out = replace(again, hand_scale=hand_scale)
                break
    if overrides is not None:
        if isinstance(overrides, (str, os.PathLike)):
            overrides = read_label_overrides(overrides)
        out = apply_label_overrides(out, overrides)
    return out


def explained_points(markers, marker_colors, points, colors, indices, gate: float) -> int:
    """How many of the points ``indices`` lie within ``gate`` of a marker of their colour among
    ``markers`` (a fitted hand's marker positions, shape (m, 3))."""
    own = np.asarray(indices, int)
    if not len(own):
        return 0
    d = np.linalg.norm(np.asarray(points)[own][:, None, :] - np.asarray(markers)[None, :, :], axis=2)
    d[np.asarray(colors)[own][:, None] != np.asarray(marker_colors)[None, :]] = np.inf
    return int(np.sum(d.min(axis=1) <= gate))


def flashes_at_one_place(labels: HandLabels, gate_m: float = GATE_M) -> list:
    """Pairs of posed flashes ``(a, b, n)`` where flash ``b``'s fitted hand explains ``n >= 3``
    of flash ``a``'s labelled points (a marker of their colour within ``gate_m`` times the hand's
    size). Flashes of one strobe sequence are at different places, so any pair means two hands
    were made of one flash's points: at least one of them is labelled wrong."""
    gate = float(gate_m) * labels.hand_scale
    posed = [k for k in range(labels.n_flashes) if labels.fits[k] is not None and (labels.point_index[k] >= 0).any()]
    pred = {k: labels.markerset.positions(labels.fits[k].pose) for k in posed}
    out = []
    for a in posed:
        own = labels.point_index[a][labels.point_index[a] >= 0]
        for b in posed:
            if b != a:
                n = explained_points(pred[b], labels.marker_colors, labels.points, labels.colors, own, gate)
                if n >= len(BACK_MARKERS):
                    out.append((a, b, n))
    return out


def _false_triplets(model, pts, cols, flashes, source, gate, link) -> tuple[list, list]:
    """Back-of-hand triplets (frozensets of point indices) of flashes posed from a triplet whose
    labelled points another posed flash's fitted hand explains better than the other way round.

    Hand ``b`` explains a point when one of its fitted markers of the point's colour lies within
    ``gate`` of it. Two flashes of one strobe sequence are at different places (the hand moves
    between flashes), so a posed hand explains no point of another flash; a false triplet (three
    markers of a flash whose back is unseen, at the back's distances and colours) is a second
    hand at the place of its flash's real one: that one, posed from the rest of the flash's
    points, explains the false hand's points (at least the triplet's three), while the false
    hand, posed wrong, explains fewer of the real one's. Nothing here assumes a speed.

    Returns ``(false, suspect)``: ``suspect`` are the other triplets whose flash has a flash
    without a pose within ``link`` (single linkage) holding more points than the triplet's hand
    labelled (the real hand could not be posed: only labelling again without it can tell)."""
    posed = [k for k, f in enumerate(flashes) if f[2] is not None and f[1]]
    pred = {k: model.markerset.positions(flashes[k][2].pose) for k in posed}

    def explains(b, a):
        return explained_points(pred[b], model.colors, pts, cols, list(flashes[a][1].values()), gate)

    back = [model.markerset.index(b) for b in BACK_MARKERS]
    unposed = [f[3] for f in flashes if f[2] is None and len(f[3])]
    out, suspect = [], []
    for a in posed:
        if source[a] != "triplet" or not all(j in flashes[a][1] for j in back):
            continue
        trip = frozenset(int(flashes[a][1][j]) for j in back)
        if any(b != a and explains(b, a) >= len(back) and explains(b, a) > explains(a, b) for b in posed):
            out.append(trip)
            continue
        own = pts[sorted(flashes[a][1].values())]
        if any(len(mem) > len(own) and np.linalg.norm(own[:, None] - pts[mem][None], axis=2).min() <= link
               for mem in unposed):
            suspect.append(trip)
    return out, suspect


def _drop_lone_unconfirmed(model, point_index: np.ndarray, unconfirmed: np.ndarray) -> None:
    """Unlabel (in place) the unconfirmed points that are the only labelled marker of their digit
    in their flash: one marker (3 coordinates) on a digit of 3-4 free angles leaves no residual,
    so the label is untested; with a second marker the digit's bone lengths test both."""
    for k in range(len(point_index)):
        for dig in model.digits:
            lab = point_index[k, dig.markers]
            have = lab >= 0
            if have.sum() == 1 and unconfirmed[lab[have][0]]:
                point_index[k, dig.markers[have][0]] = -1


def contradicted_labels(labels: HandLabels, residuals, flashes, unconfirmed, gate_m: float = GATE_M) -> np.ndarray:
    """Unconfirmed points (``label_hand_markers``' ``unconfirmed``) whose residual in a later fit
    exceeds the labelling gate (``gate_m`` times the hand's size): the fit that weighs each point
    by its own noise says they are not the marker their label names (the labeller's fit, which
    weighs all points alike, bent the digit to them). Back-of-hand markers are never returned
    (they define the flash).

    Parameters
    ----------
    labels : HandLabels
    residuals : array_like, shape (n, n_markers)
        Distance of each labelled marker from the fitted model (m), NaN where unlabelled
        (:attr:`HandSequence.residuals <stillcap.body.hand_track.HandSequence.residuals>`).
    flashes : array_like of int, shape (n,)
        The labels' flash of each row of ``residuals``.
    unconfirmed : array_like of bool, shape (len(labels.points),)
    gate_m : float

    Returns
    -------
    ndarray of int
        Point indices.
    """
    res = np.asarray(residuals, float)
    unconfirmed = np.asarray(unconfirmed, bool)
    back = {labels.marker_names.index(n) for n in BACK_MARKERS}
    gate = float(gate_m) * labels.hand_scale
    out = []
    for i, k in enumerate(np.asarray(flashes, int)):
        for j in np.flatnonzero(np.nan_to_num(res[i], nan=0.0) > gate):
            p = int(labels.point_index[k, j])
            if p >= 0 and j not in back and unconfirmed[p]:
                out.append(p)
    return np.array(sorted(out), int)


def unlabel_points(labels: HandLabels, point_indices) -> HandLabels:
    """The labels without the given points' labels (the points become unassigned)."""
    drop = np.isin(labels.point_index, np.asarray(point_indices, int)) & (labels.point_index >= 0)
    if not drop.any():
        return labels
    pi = np.where(drop, -1, labels.point_index)
    pos = np.where(drop[..., None], np.nan, labels.positions)
    used = set(pi[pi >= 0].tolist()) | set(np.asarray(labels.deleted).tolist())
    unassigned = np.array([i for i in range(len(labels.points)) if i not in used
                           and np.all(np.isfinite(labels.points[i]))], int)
    return replace(labels, point_index=pi, positions=pos, unassigned=unassigned)


def _build(model, pts, cols, strobe_hz, point_index, fits, skipped, members, deleted,
           hand_scale: float = 1.0, source=None) -> HandLabels:
    n, m = point_index.shape
    positions = np.where((point_index >= 0)[..., None], pts[np.maximum(point_index, 0)], np.nan)
    used = set(point_index[point_index >= 0].tolist()) | set(np.asarray(deleted).tolist())
    unassigned = np.array([i for i in range(len(pts)) if i not in used and np.all(np.isfinite(pts[i]))], int)
    rms = np.array([np.nan if f is None else f.rms for f in fits])
    order = np.arange(n)
    return HandLabels(list(model.markerset.names), list(model.colors), order, order / strobe_hz, strobe_hz,
                      point_index, positions, np.array([f is not None for f in fits], bool), list(skipped),
                      [np.asarray(x, int) for x in members], unassigned, np.asarray(deleted, int), rms, list(fits),
                      pts, cols, model.skeleton, model.markerset, float(hand_scale),
                      list(source) if source is not None else ["triplet" if f is not None else "" for f in fits])


# --------------------------------------------------------------------------------------------
# Manual overrides
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LabelOverride:
    """One manual correction: the point of ``flash`` nearest ``position`` (within
    ``tolerance_m``) gets ``label``, or is deleted.

    Attributes
    ----------
    flash : int
        Flash in time order (:attr:`HandLabels.order`).
    position : ndarray, shape (3,)
        Where the point is (field frame, m).
    label : str or None
        A marker name; None with ``delete``.
    delete : bool
    tolerance_m : float
    entry : str
        How error messages name this entry (e.g. ``"override 3 in labels.json"``).
    """

    flash: int
    position: np.ndarray
    label: str | None = None
    delete: bool = False
    tolerance_m: float = 0.003
    entry: str = "override"


def read_label_overrides(path) -> list[LabelOverride]:
    """Read manual label corrections from a JSON file.

    Format (``docs/hand-labelling.md``)::

        {"format": "stillcap-label-overrides", "version": 1, "tolerance_mm": 3,
         "overrides": [{"flash": 1, "position_m": [x, y, z], "label": "index.nail"},
                       {"flash": 2, "position_m": [x, y, z], "delete": true}]}

    An entry may carry its own ``tolerance_mm``. Errors name the file and the entry.
    """
    data = read_json(path, "label overrides file")
    where = f"label overrides file {path}"
    if not isinstance(data, dict) or data.get("format", _OVERRIDES_FORMAT) != _OVERRIDES_FORMAT:
        raise ValueError(f"{where}: expected a JSON object with format {_OVERRIDES_FORMAT!r}")
    f = validate(OverridesFile, data, where)
    tol = (3.0 if f.tolerance_mm is None else f.tolerance_mm) / 1000
    out = []
    for k, e in enumerate(f.overrides):
        name = f"{where}: overrides.{k}"
        if e.delete == (e.label is not None):
            raise ValueError(f"{name}: needs either a 'label' or \"delete\": true (not both)")
        t = tol if e.tolerance_mm is None else e.tolerance_mm / 1000
        out.append(LabelOverride(e.flash, np.asarray(e.position_m, float), e.label, e.delete, t, name))
    return out


def apply_label_overrides(labels: HandLabels, overrides) -> HandLabels:
    """Apply manual corrections and refit the flashes they touch.

    Each override finds, among all points not yet deleted, the one nearest its position; it
    must lie within its tolerance. A relabel moves the point to ``(flash, label)`` (the point
    that had that label becomes unassigned); a delete removes the point. A flash that gets its
    three back-of-hand markers is fitted (so an override can rescue a skipped flash); one that
    loses them is skipped, unless it was posed from its other markers in the first place
    (``pose_source`` ``"neighbours"``) and keeps :data:`MIN_MARKERS` labels.

    Parameters
    ----------
    labels : HandLabels
    overrides : sequence of LabelOverride

    Returns
    -------
    HandLabels
        A new result; ``labels`` is left unchanged.
    """
    ms = labels.markerset
    model = LabelModel.__new__(LabelModel)  # only the cheap parts are needed here
    model.skeleton, model.markerset = labels.skeleton, ms
    model.colors = np.asarray(labels.marker_colors)
    pi = labels.point_index.copy()
    deleted = set(labels.deleted.tolist())
    members = [set(m.tolist()) for m in labels.members]
    touched = set()
    for o in overrides:
        if not isinstance(o, LabelOverride):
            raise ValueError(f"overrides must be LabelOverride objects, got {type(o).__name__}")
        if not 0 <= o.flash < labels.n_flashes:
            raise ValueError(f"{o.entry}: flash {o.flash} is not one of the {labels.n_flashes} flashes (0..{labels.n_flashes - 1})")
        cand = np.array([i for i in range(len(labels.points)) if i not in deleted and np.all(np.isfinite(labels.points[i]))], int)
        d = np.linalg.norm(labels.points[cand] - o.position, axis=1) if len(cand) else np.array([])
        if not len(d) or d.min() > o.tolerance_m:
            near = f"; the nearest point is {d.min() * 1000:.1f} mm away" if len(d) else ""
            raise ValueError(f"{o.entry}: no point within {o.tolerance_m * 1000:g} mm of {np.round(o.position, 4).tolist()}{near}")
        p = int(cand[np.argmin(d)])
        for k in np.flatnonzero((pi == p).any(axis=1)):
            touched.add(int(k))
        pi[pi == p] = -1
        for mem in members:
            mem.discard(p)
        touched.add(o.flash)
        if o.delete:
            deleted.add(p)
        else:
            if o.label not in ms.names:
                raise ValueError(f"{o.entry}: unknown marker {o.label!r}; markers: {', '.join(ms.names)}")
            pi[o.flash, ms.index(o.label)] = p
            members[o.flash].add(p)
    fits, skipped = list(labels.fits), list(labels.skipped)
    source = list(labels.pose_source) or ["triplet" if f is not None else "" for f in fits]
    back = [ms.index(b) for b in BACK_MARKERS]
    for k in sorted(touched):
        pos = np.where((pi[k] >= 0)[:, None], labels.points[np.maximum(pi[k], 0)], np.nan)
        if np.all(pi[k, back] >= 0):
            init = fits[k].pose if fits[k] is not None else (next((f.pose for f in fits if f is not None), None))
            fits[k] = fit_hand(labels.skeleton, ms, pos, initial=init)
            skipped[k], source[k] = "", "overrides"
        elif fits[k] is not None and source[k] == "neighbours" and (pi[k] >= 0).sum() >= MIN_MARKERS:
            fits[k] = fit_hand(labels.skeleton, ms, pos, initial=fits[k].pose)  # posed from its other markers
            skipped[k] = ""
        else:
            fits[k] = None
            miss = [BACK_MARKERS[j] for j in range(3) if pi[k, back[j]] < 0]
            skipped[k], source[k] = f"back-of-hand markers missing after manual overrides: {', '.join(miss)}", ""
    return _build(model, labels.points, labels.colors, labels.strobe_hz, pi, fits, skipped,
                  [np.array(sorted(m), int) for m in members], np.array(sorted(deleted), int), labels.hand_scale,
                  source)


# --------------------------------------------------------------------------------------------
# Synthetic input from the studio's truth
# --------------------------------------------------------------------------------------------
def hand_points_from_truth(truth, *, noise_m: float = 0.0005, drop: float = 0.05, n_spurious: int = 3,
                           min_views: int = 2, rng=None) -> dict:
    """Unlabelled points as the 3D marker stage gives them, made from a studio hand truth.

    Markers seen by ``min_views`` cameras (``truth.markers_visible``) are kept, a share
    ``drop`` of them is dropped at random (missed matches), Gaussian noise of ``noise_m`` per
    axis is added, ``n_spurious`` points of random colours are placed near the hands (wrong
    stereo matches), and everything is shuffled.

    Returns
    -------
    dict
        ``points`` (N, 3), ``colours`` (N,), and the truth per point: ``flash`` (index into the
        truth's flashes, -1 spurious) and ``marker`` (-1 spurious).
    """
    rng = as_rng(rng)
    vis = np.asarray(truth.markers_visible).sum(axis=0) >= min_views  # (n, m)
    keep = vis & (rng.random(vis.shape) >= drop)
    f, mk = np.nonzero(keep)
    pts = truth.markers[f, mk] + rng.normal(0, noise_m, (len(f), 3))
    cols = np.asarray(truth.marker_colors)[mk]
    allm = truth.markers.reshape(-1, 3)
    lo, hi = allm.min(axis=0) - 0.03, allm.max(axis=0) + 0.03
    sp = rng.uniform(lo, hi, (n_spurious, 3))
    spc = rng.choice(sorted(HAND_COLORS), n_spurious)
    pts = np.concatenate([pts, sp])
    cols = np.concatenate([cols, spc])
    f = np.concatenate([f, np.full(n_spurious, -1)])
    mk = np.concatenate([mk, np.full(n_spurious, -1)])
    perm = rng.permutation(len(pts))
    return {"points": pts[perm], "colours": cols[perm], "flash": f[perm], "marker": mk[perm]}
