"""Labels filled in where the first pass of the glove labelling leaves them out (issue 12).

On hands unlike the model the first pass (:func:`stillcap.body.hand_label.label_hand_markers`,
steps 1-5) labelled only 58-89 % of the markers seen by two or more cameras. Most of the others
were in flashes whose back-of-hand triplet was not found (one back marker hidden: the flash got
no pose at all); the rest were points the model's 8 mm gate did not reach (a finger of other
proportions puts its PIP marker 9-18 mm from the model's). Two steps label what is there,
without trading correctness for coverage:

:func:`pose_from_neighbours`
    A flash without a pose is posed from whatever markers it has, with a neighbouring flash's
    pose as the prior. The hand changes shape little from one flash to the next, so the
    neighbour's fitted joint angles give a template of all markers in the hand frame. Every
    triple of the flash's points whose colours and mutual distances match three template
    markers (within :data:`PAIR_TOL_M`, times the hand's size: fingers move between flashes)
    is a hypothesis of the root pose (rigid alignment, the Kabsch method vectorised over the hypotheses).
    The best hypotheses (markers of the template within the grid gate of a point of their
    colour) are refined as a flash with a back-of-hand triplet is: best grid pose per digit,
    the hand fitted, points assigned optimally (:func:`scipy.optimize.linear_sum_assignment`)
    until the labels stop changing. A label is kept only when every competitive hypothesis
    (within :data:`COMPETE_MARKERS` markers of the best and fitting as well) gives that point
    the same marker: ambiguous evidence leaves the points unlabelled. A hypothesis with fewer
    markers than the best that bends the hand :data:`SHAPE_RATIO` times as much from the
    neighbouring flash (:func:`shape_change_deg`) does not compete. The flash is posed when
    :data:`~stillcap.body.hand_label.MIN_MARKERS` agreed labels remain. Flashes are posed
    nearest a posed flash first, so a newly posed flash is a neighbour for the next.
:func:`label_leftovers`
    After the fits, a point left over near a posed hand is labelled when exactly one unlabelled
    marker of its colour lies within the wider gate (:data:`LEFTOVER_GATE_FACTOR` times the
    assignment gate) and that marker has no other candidate point, and no other marker of that
    colour (labelled or not, of any posed flash) lies within the gate of the point, and another
    flash shows the same marker off the fitted model the same way (its offset in the hand frame
    within the assignment gate): a model of other proportions misses a marker alike in every
    flash, a stray point near a marker whose own point is missing does not. Two candidates
    within the gate leave both unlabelled. The flash is refitted and the ordinary
    assignment runs again, a few rounds.

Both keep the points they cannot label in ``unassigned`` (the result lists them), and the
self-check ``unlabelled_markers`` counts them.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.body.hand_grid import LabelModel, assign_points, fit_labels, grid_match
from stillcap.body.skeleton import Pose

__all__ = ["COMPETE_MARKERS", "LEFTOVER_GATE_FACTOR", "PAIR_TOL_M", "SHAPE_RATIO", "digit_search", "label_leftovers",
           "pose_from_neighbours", "pose_one_flash", "shape_change_deg", "template_markers"]

#: Tolerance on each distance between three points of a flash and the three template markers
#: they are taken for (m, for a hand of the model's size): the fingers move between flashes.
PAIR_TOL_M = 0.012
#: Sides of a hypothesis triangle shorter than this (m, model size) do not fix a rotation well.
MIN_SIDE_M = 0.015
#: Hypotheses refined per template (the best by markers matched).
N_REFINE = 12
#: A refined hypothesis competes with the best when it labels at most this many markers fewer
#: than the one labelling most and fits within the assignment gate.
COMPETE_MARKERS = 2
#: A labelling with fewer markers than the best one does not compete with it when its fit changes
#: the hand's joint angles from the neighbouring flash's (RMS, :func:`shape_change_deg`) more than
#: this many times as much as the best one's. On the studio's first flashes without a back-of-hand
#: triplet (hands 2 and 8, both models) the right labelling changed them 1.9-10 deg and its rivals
#: 1.9-9 times as much (15.8-30 deg).
SHAPE_RATIO = 1.5
#: The second pass's gate, in multiples of the assignment gate (8 mm x the hand's size): on
#: hands of other proportions the unreached markers were 9-18 mm from the fitted model, the
#: nearest other marker of their colour 29 mm or more.
LEFTOVER_GATE_FACTOR = 2.5
#: Rounds of the second pass.
LEFTOVER_ROUNDS = 3


def shape_change_deg(angles_deg, prior_deg) -> float:
    """RMS change of the joint angles from a neighbouring flash's (deg): how much a labelling makes
    the hand change shape between flashes."""
    d = np.asarray(angles_deg, float) - np.asarray(prior_deg, float)
    return float(np.sqrt(np.nanmean(d ** 2)))


def template_markers(model: LabelModel, angles_deg) -> np.ndarray:
    """The model's markers in the hand (root) frame for joint angles ``angles_deg`` (n_joints, 3),
    shape (n_markers, 3)."""
    rot = Rotation.from_euler("XYZ", np.asarray(angles_deg, float), degrees=True).as_matrix()
    return model.markerset.positions(Pose(model.skeleton, np.eye(4), rot))


def _hypotheses(T, tcols, P, pcols, tol, min_side):
    """Index triples ``(i, j, l)`` of points and ``(a, b, c)`` of template markers whose colours
    and three mutual distances agree; shapes (H, 3), (H, 3)."""
    DT = np.linalg.norm(T[:, None] - T[None], axis=-1)
    DP = np.linalg.norm(P[:, None] - P[None], axis=-1)
    C = pcols[:, None] == tcols[None]
    pts_idx, mk_idx = [], []
    n = len(P)
    for i in range(n):
        for j in range(i + 1, n):
            if DP[i, j] < min_side:
                continue
            A, B = np.nonzero(C[i][:, None] & C[j][None] & (np.abs(DT - DP[i, j]) < tol))
            if not len(A):
                continue
            for l in range(j + 1, n):
                if DP[i, l] < min_side or DP[j, l] < min_side:
                    continue
                ok = C[l][None] & (np.abs(DT[A] - DP[i, l]) < tol) & (np.abs(DT[B] - DP[j, l]) < tol)
                ok[np.arange(len(A)), A] = False
                ok[np.arange(len(B)), B] = False
                r, c = np.nonzero(ok)
                for rr, cc in zip(r, c):
                    pts_idx.append((i, j, l))
                    mk_idx.append((A[rr], B[rr], cc))
    return np.array(pts_idx, int).reshape(-1, 3), np.array(mk_idx, int).reshape(-1, 3)


def _kabsch(src, dst):
    """Rigid transforms (H, 4, 4) taking ``src`` (H, k, 3) onto ``dst`` (H, k, 3), and the RMS
    of each alignment (H,). Vectorised over the hypotheses (``rigid_alignment`` does one)."""
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    H = np.einsum("hki,hkj->hij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("hij,hjk->hik", U, Vt)))
    D = np.tile(np.eye(3), (len(src), 1, 1))
    D[:, 2, 2] = d
    R = np.einsum("hji,hjk,hlk->hil", Vt, D, U)  # V D U^T
    out = np.tile(np.eye(4), (len(src), 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = cd - np.einsum("hij,hj->hi", R, cs)
    rms = np.sqrt(np.mean(np.sum((np.einsum("hij,hkj->hki", R, src) + out[:, None, :3, 3] - dst) ** 2, -1), -1))
    return out, rms


def _score(T, tcols, P, pcols, r2w, gate):
    """Markers of each hypothesis' template within ``gate`` of a point of their colour (H,), and
    the sum of their squared distances (capped at the gate) (H,)."""
    hits = np.zeros(len(r2w), int)
    cost = np.zeros(len(r2w))
    for s in range(0, len(r2w), 2000):
        R, t = r2w[s:s + 2000, :3, :3], r2w[s:s + 2000, :3, 3]
        W = np.einsum("hij,mj->hmi", R, T) + t[:, None]
        d = np.linalg.norm(W[:, :, None] - P[None, None], axis=-1)
        d = np.where((tcols[:, None] == pcols[None])[None], d, np.inf).min(axis=2)
        hits[s:s + 2000] = (d < gate).sum(axis=1)
        cost[s:s + 2000] = np.minimum(d, gate).__pow__(2).sum(axis=1)
    return hits, cost


def _refine(model, pts, cols, avail, r2w, prior_angles, grid_gate, gate, max_iter=4):
    """A root pose hypothesis refined: grid pose per digit, fit, optimal assignment until the
    labels stop changing. ``(labels {marker: point}, fit)`` or ``(None, None)``."""
    labels, angles, _, _ = grid_match(model, r2w, pts, cols, avail, grid_gate, prior_angles)
    if len(labels) < 3:
        return None, None
    initial = Pose(model.skeleton, r2w, Rotation.from_euler("XYZ", angles, degrees=True).as_matrix())
    fit, _ = fit_labels(model, pts, labels, initial)
    for _ in range(max_iter):
        new = assign_points(model, model.markerset.positions(fit.pose), pts, cols, avail, gate, {})
        if new == labels or len(new) < 3:
            break
        labels = new
        fit, _ = fit_labels(model, pts, labels, fit.pose)
    return labels, fit


def pose_one_flash(model: LabelModel, pts, cols, members, templates, *, grid_gate: float, gate: float,
                   min_markers: int, pair_tol: float, min_side: float):
    """Labels and fit of one flash without a back-of-hand triplet (module docstring).

    Parameters
    ----------
    model : LabelModel
        The (scaled) hand model.
    pts, cols : ndarray, shapes (N, 3), (N,)
        All points and colours.
    members : array_like of int
        The flash's points.
    templates : list of ndarray, shape (n_joints, 3)
        Joint angles (degrees) of neighbouring posed flashes.
    grid_gate, gate, pair_tol, min_side : float
        Already scaled to the hand's size (m).

    Returns
    -------
    (dict, HandFit) or (None, str)
        The agreed labels {marker: point} and the fit, or None and why not.
    """
    members = np.asarray(members, int)
    avail = np.zeros(len(pts), bool)
    avail[members] = True
    P, pc = pts[members], cols[members]
    refined = []
    for angles in templates:
        T = template_markers(model, angles)
        pi, mi = _hypotheses(T, model.colors, P, pc, pair_tol, min_side)
        if not len(pi):
            continue
        r2w, rms = _kabsch(T[mi], P[pi])
        keep = rms < pair_tol
        r2w = r2w[keep]
        if not len(r2w):
            continue
        hits, cost = _score(T, model.colors, P, pc, r2w, grid_gate)
        order = np.lexsort((cost, -hits))
        seen_poses = []
        for h in order:
            if len(seen_poses) >= N_REFINE:
                break
            # hypotheses from other triples of the same hand give (almost) the same root pose
            if any(np.linalg.norm(r2w[h, :3, 3] - q[:3, 3]) < gate and
                   np.linalg.norm(r2w[h, :3, :3] - q[:3, :3]) < 0.1 for q in seen_poses):
                continue
            seen_poses.append(r2w[h])
            labels, fit = _refine(model, pts, cols, avail, r2w[h], angles, grid_gate, gate)
            if labels is not None:
                refined.append((labels, fit, angles))
    if not refined:
        return None, "no three of its points match a neighbouring flash's markers"
    good = [(lab, f, a) for lab, f, a in refined if f.rms < gate]
    if not good:
        return None, "no pose from its other markers fits within the gate"
    most = max(len(lab) for lab, _, _ in good)
    best = max(good, key=lambda x: (len(x[0]), -x[1].rms))
    # the whole hand's fit judges the rivals too: a labelling with fewer markers than the best
    # that also needs the hand to change shape from the neighbouring flash SHAPE_RATIO times as
    # much does not compete (the hand changes shape little from one flash to the next; a wrong
    # labelling bends the digits to reach its points)
    best_change = shape_change_deg(best[1].angles_deg, best[2])
    compete = [lab for lab, f, a in good if len(lab) >= most - COMPETE_MARKERS
               and not (len(lab) < len(best[0]) and shape_change_deg(f.angles_deg, a) > SHAPE_RATIO * best_change)]
    # a label is kept when no competing labelling gives its marker another point or its point
    # another marker (a labelling that leaves either out does not contradict it)
    inverse = [{p: m for m, p in lab.items()} for lab in compete]
    agreed = {m: p for m, p in best[0].items()
              if all(lab.get(m, p) == p and inv.get(p, m) == m for lab, inv in zip(compete, inverse))}
    if len(agreed) < min_markers:
        return None, (f"its other markers give {len(compete)} competing labellings that agree on only "
                      f"{len(agreed)} points (a pose needs {min_markers})")
    # the joints start from the neighbour's angles, not the hypothesis' grid pose: a digit with one
    # marker or none leaves its angles to the start, a grid pose of it is arbitrary (a ring finger
    # with its nail marker alone came out 47 deg off at the DIP), and the sequence fit starts the
    # next flash from this one; the grid pose's fit is kept only when it fits clearly better
    start = Pose(model.skeleton, best[1].pose.root2world,
                 Rotation.from_euler("XYZ", best[2], degrees=True).as_matrix())
    fit, _ = fit_labels(model, pts, agreed, start)
    grid_fit, _ = fit_labels(model, pts, agreed, best[1].pose)
    if grid_fit.rms < 0.5 * fit.rms - 1e-4:
        fit = grid_fit
    if fit.rms >= gate:
        return None, "its agreed labels do not fit the hand within the gate"
    return agreed, fit


def pose_from_neighbours(model: LabelModel, pts, cols, flashes: list, *, grid_gate: float, gate: float,
                         min_markers: int, pair_tol: float, min_side: float) -> list:
    """Pose the flashes without a pose from their neighbours (module docstring).

    ``flashes`` is the labelling's list in time order, each ``[position, labels or None, fit or
    None, members, why]``; the flashes posed here get their labels, fit and members, and
    ``why`` becomes "" (their reason for having no pose is replaced when they stay without one).
    Returns the indices of the flashes posed here.
    """
    posed_here, tried, why = [], {}, {}
    while True:
        posed = [k for k, f in enumerate(flashes) if f[2] is not None]
        # a flash is tried again only when more flashes have a pose than at its last try
        todo = [k for k, f in enumerate(flashes) if f[2] is None and tried.get(k, -1) < len(posed)]
        if not todo:
            break
        if not posed:  # no prior: the rest pose would be a guess about the hand's shape
            break
        k = min(todo, key=lambda q: min(abs(q - p) for p in posed))
        tried[k] = len(posed)
        templates = [flashes[q][2].angles_deg for q in sorted(posed, key=lambda q: abs(k - q))[:2]]
        labels, fit = pose_one_flash(model, pts, cols, flashes[k][3], templates, grid_gate=grid_gate, gate=gate,
                                     min_markers=min_markers, pair_tol=pair_tol, min_side=min_side)
        if labels is None:
            why[k] = fit
            continue
        flashes[k][1], flashes[k][2], flashes[k][4] = labels, fit, ""
        flashes[k][3] = np.array(sorted(labels.values()), int)
        posed_here.append(k)
    for k, w in why.items():
        if flashes[k][2] is None:
            flashes[k][4] = f"{flashes[k][4]}; posing it from its other markers failed: {w}"
    return posed_here


def label_leftovers(model: LabelModel, pts, cols, avail, flashes: list, *, gate: float, factor: float = LEFTOVER_GATE_FACTOR,
                    rounds: int = LEFTOVER_ROUNDS) -> int:
    """Label points left over near posed hands (module docstring); ``flashes`` as in
    :func:`pose_from_neighbours` (updated in place), ``avail`` (N,) bool the points not labelled
    yet (updated). Returns the number of points labelled."""
    wide = factor * gate
    n_new = 0
    posed = [k for k, f in enumerate(flashes) if f[2] is not None]
    for _ in range(rounds):
        left = np.flatnonzero(avail)
        if not len(left) or not posed:
            break
        pred = {k: model.markerset.positions(flashes[k][2].pose) for k in posed}
        # every (flash, marker) within the wide gate of each left-over point, labelled or not
        cand = {}  # point -> list of (flash, marker, distance)
        for k in posed:
            d = np.linalg.norm(pts[left][:, None] - pred[k][None], axis=-1)
            same = cols[left][:, None] == model.colors[None]
            for a, m in zip(*np.nonzero(same & (d < wide))):
                cand.setdefault(int(left[a]), []).append((k, int(m), float(d[a, m])))
        per_marker = {}
        for p, cs in cand.items():
            for k, m, _ in cs:
                per_marker.setdefault((k, m), []).append(p)
        # where each marker's points sit relative to the fitted model, in the hand frame, per flash:
        # a model of other proportions misses a marker the same way in every flash; a stray point
        # near a marker whose own point is missing does not (it gave the one wrong label)
        def offset(k, m, p):
            r2w = flashes[k][2].pose.root2world
            return r2w[:3, :3].T @ (pts[p] - pred[k][m])

        seen_off = {}  # marker -> [(flash, offset)] of its labelled points and its candidates
        for k in posed:
            for m, p in flashes[k][1].items():
                seen_off.setdefault(m, []).append((k, offset(k, m, p)))
        for p, cs in cand.items():
            for k, m, _ in cs:
                seen_off.setdefault(m, []).append((k, offset(k, m, p)))
        changed = set()
        for p, cs in cand.items():
            if len(cs) != 1:
                continue  # two markers within the gate: ambiguous
            k, m, _ = cs[0]
            if m in flashes[k][1] or len(per_marker[(k, m)]) != 1:
                continue  # the marker has its point already, or two points want it
            o = offset(k, m, p)
            if not any(q != k and np.linalg.norm(o - oq) < gate for q, oq in seen_off.get(m, [])):
                continue  # no other flash misses this marker the same way
            flashes[k][1][m] = p
            avail[p] = False
            changed.add(k)
            n_new += 1
        if not changed:
            break
        for k in changed:  # refit, then the ordinary assignment may reach more
            labels = flashes[k][1]
            fit, _ = fit_labels(model, pts, labels, flashes[k][2].pose)
            free = avail.copy()
            free[list(labels.values())] = True
            new = assign_points(model, model.markerset.positions(fit.pose), pts, cols, free, gate, labels)
            for m, p in new.items():
                if m not in labels:
                    avail[p] = False
                    n_new += 1
            if new != labels:
                fit, _ = fit_labels(model, pts, new, fit.pose)
            flashes[k][1], flashes[k][2] = new, fit
            flashes[k][3] = np.array(sorted(new.values()), int)
    return n_new



# --------------------------------------------------------------------------------------------
# Markers looked for where the posed hand puts them (issue 12)
# --------------------------------------------------------------------------------------------
def bone_offsets(skeleton, markerset, poses, positions) -> np.ndarray:
    """Each measured marker's offset from the fitted model's, in the frame of the marker's bone.

    Parameters
    ----------
    skeleton, markerset
        The hand the poses are of.
    poses : sequence of Pose, length n
    positions : array_like, shape (n, n_markers, 3)
        The measured markers of each pose's flash (world, m), NaN where unlabelled.

    Returns
    -------
    ndarray, shape (n, n_markers, 3)
        Bone frame, m; NaN where unlabelled.
    """
    frames = markerset.bone_frames(skeleton)
    positions = np.asarray(positions, float)
    out = np.full(positions.shape, np.nan)
    for i, pose in enumerate(poses):
        rot = pose.joint2world[frames, :3, :3]
        out[i] = np.einsum("mji,mj->mi", rot, positions[i] - markerset.positions(pose))
    return out


def median_of_others(offsets, usable) -> np.ndarray:
    """Per flash and marker, the median of ``offsets`` (shape (n, n_markers, 3)) over the *other*
    flashes where ``usable`` (bool, shape (n, n_markers)) holds; NaN where there is none. A model
    of other proportions misses a marker the same way in every flash, in the frame of its bone
    (a longer phalanx puts it farther along its bone whatever the joint angles), so the offset
    the capture shows elsewhere is the model's error in this flash (:func:`predicted_missing`,
    :func:`stillcap.pipelines.hand.stages.misfit_residuals`)."""
    offsets = np.asarray(offsets, float)
    usable = np.asarray(usable, bool) & np.isfinite(offsets[..., 0])
    out = np.full(offsets.shape, np.nan)
    for i in range(len(offsets)):
        other = usable.copy()
        other[i] = False
        for m in np.flatnonzero(other.any(axis=0)):
            out[i, m] = np.median(offsets[other[:, m], m], axis=0)
    return out


def predicted_missing(labels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the posed flashes' fitted hands put their unlabelled markers.

    Each prediction is the fitted model's marker moved by that marker's median offset from the
    fitted model in the other posed flashes that label it, in the frame of the marker's bone
    (:func:`median_of_others`). Without such a flash the model's marker is used.

    Returns
    -------
    flash, marker : ndarray of int, shape (P,)
    predicted : ndarray, shape (P, 3)
        World, m.
    """
    posed = [k for k in range(labels.n_flashes) if labels.fits[k] is not None]
    poses = [labels.fits[k].pose for k in posed]
    frames = labels.markerset.bone_frames(labels.skeleton)
    offs = bone_offsets(labels.skeleton, labels.markerset, poses, labels.positions[posed])
    med = median_of_others(offs, labels.point_index[posed] >= 0)
    flash, marker, out = [], [], []
    for i, (k, pose) in enumerate(zip(posed, poses)):
        model, rot = labels.markerset.positions(pose), pose.joint2world[frames, :3, :3]
        for m in np.flatnonzero(labels.point_index[k] < 0):
            shift = rot[m] @ med[i, m] if np.isfinite(med[i, m, 0]) else np.zeros(3)
            flash.append(k), marker.append(int(m)), out.append(model[m] + shift)
    return np.array(flash, int), np.array(marker, int), np.array(out, float).reshape(-1, 3)


def whole_labels(labels, flashes, unconfirmed) -> np.ndarray:
    """Per flash of ``flashes`` and marker: labelled with a point that is not ``unconfirmed``
    (bool per point), shape (n, n_markers)."""
    pi = labels.point_index[np.asarray(flashes, int)]
    return (pi >= 0) & ~np.asarray(unconfirmed, bool)[np.maximum(pi, 0)]


def root_fixed(labels, flashes, unconfirmed) -> np.ndarray:
    """Per flash of ``flashes``: whether its three back-of-hand markers are labelled with points
    that are not ``unconfirmed`` (bool per point). Only then do whole markers fix the hand's
    root: a whole finger marker sits on a digit with free angles and says little about it."""
    from stillcap.body.hand import BACK_MARKERS

    back = [labels.marker_names.index(n) for n in BACK_MARKERS]
    return whole_labels(labels, flashes, unconfirmed)[:, back].all(axis=1)


def on_back_triangle(labels, points, proposals, *, unconfirmed=None, tol_m: float) -> np.ndarray:
    """Which proposals of back-of-hand markers lie where the hand's own back-of-hand triangle
    puts them: per proposal ``(point, flash, marker)``, True when its marker is a back-of-hand
    one and its point lies within ``tol_m`` of the triangle's side from every other back-of-hand
    marker of its flash that a point carries (its label, or another such proposal), with at
    least one such partner. The sides are measured on this capture: the median distances
    between the back-of-hand points of the flashes that label all three with points that are
    not ``unconfirmed`` (bool per point); without such a flash nothing is True.

    The back of the hand is rigid, so the sides hold in every flash whatever the pose; in a
    flash posed without its triplet (:func:`pose_from_neighbours`) the fitted root, and so the
    prediction, can be 10 mm off (studio hand 12, its flash 0), while a partly hidden
    ``back.3`` lies 0.2 mm from its side to ``back.1``."""
    from stillcap.body.hand import BACK_MARKERS

    pts = np.asarray(points, float)
    unconfirmed = np.zeros(len(pts), bool) if unconfirmed is None else np.asarray(unconfirmed, bool)
    back = [labels.marker_names.index(n) for n in BACK_MARKERS]
    whole = root_fixed(labels, range(len(labels.point_index)), unconfirmed)
    out = np.zeros(len(proposals), bool)
    if not whole.any():
        return out
    tri = pts[labels.point_index[whole][:, back]]  # (n, 3, 3)
    sides = np.median(np.linalg.norm(tri[:, :, None] - tri[:, None], axis=3), axis=0)
    for i, (p, k, m) in enumerate(proposals):
        if m not in back:
            continue
        partners = [(b, int(labels.point_index[k, m2])) for b, m2 in enumerate(back)
                    if m2 != m and labels.point_index[k, m2] >= 0]
        partners += [(back.index(m2), int(p2)) for p2, k2, m2 in proposals if k2 == k and m2 in back and m2 != m]
        a = back.index(m)
        out[i] = bool(partners) and all(abs(np.linalg.norm(pts[p] - pts[q]) - sides[a, b]) <= tol_m
                                        for b, q in partners)
    return out


def _digit_markers(labels) -> list[np.ndarray]:
    """Marker indices per digit (the first part of the bone's joint name, e.g. ``index``)."""
    frames = labels.markerset.bone_frames(labels.skeleton)
    names = np.array([labels.skeleton.names[f].split("-")[0] for f in frames])
    root = labels.skeleton.names[labels.skeleton.root]
    return [np.flatnonzero(names == d) for d in dict.fromkeys(names) if d != root]


def _wide_gate_safe(labels, pi, k: int, m: int, X, colour: str) -> bool:
    """Whether a point beyond the gate of marker ``m``'s prediction may still be it: the marker's
    digit has another labelled marker in flash ``k`` (so the fitted digit, and the prediction,
    rest on that flash's own points), and no digit of the flash without any labelled marker has
    a marker of the point's colour that could reach it (such a digit's fitted angles are no
    evidence: it may be its marker, wherever the fit left it)."""
    sk, ms = labels.skeleton, labels.markerset
    frames = ms.bone_frames(sk)
    names = [n.split("-")[0] for n in sk.names]
    mcol = np.asarray(labels.marker_colors).astype(str)
    j2w = labels.fits[k].pose.joint2world
    for d in _digit_markers(labels):
        digit = names[frames[d[0]]]
        if m in d:
            if not np.any(pi[k, d[d != m]] >= 0):
                return False
            continue
        if np.any(pi[k, d] >= 0) or not np.any(mcol[d] == colour):
            continue
        chain = [i for i in sk.depth_first if names[i] == digit]
        reach = sum(np.linalg.norm(sk.offsets[i]) for i in chain[1:]) + max(np.linalg.norm(ms.offsets[d], axis=1))
        if np.linalg.norm(X - j2w[chain[0], :3, 3]) <= reach:
            return False
    return True


def label_recovered(labels, points, colors, proposals, *, gate_m: float, predicted=None, confirmed=None,
                    unconfirmed=None, factor: float = LEFTOVER_GATE_FACTOR):
    """Labels for points found where the fitted hands put unlabelled markers
    (:func:`predicted_missing`, :func:`stillcap.geometry.marker_near.triangulate_near`), given
    only when they pass the labeller's own tests.

    Parameters
    ----------
    labels : HandLabels
    points : array_like, shape (N', 3)
        The capture's points: ``labels.points`` with rows changed or appended for the points
        found (a row of an unlabelled point may be replaced by the point its blobs give with
        more views).
    colours : array_like of str, shape (N',)
    proposals : sequence of (point, flash, marker)
    gate_m : float
        The labelling gate (m), for a hand of the labels' size (already scaled).
    predicted : array_like, shape (len(proposals), 3), optional
        Where :func:`predicted_missing` put each proposal's marker (default: the fitted model's
        marker).
    confirmed : array_like of bool, shape (N',), optional
        Points that three or more cameras agree on: no chance match of two blobs. Such a point
        may lie up to ``factor`` times the gate from its prediction (a model of other
        proportions misses markers by 9-18 mm, beyond the gate), when no other marker of its
        colour lies within that wider gate; other points must lie within the gate.
    unconfirmed : array_like of bool, shape (N',), optional
        As :func:`~stillcap.body.hand_label.label_hand_markers`' ``unconfirmed``.

    A proposal is dropped when its point lies within the gate of another marker of its colour
    in a fitted hand (of any posed flash, labelled or not: two markers could be its), when two
    proposals share a point, when it is unconfirmed and no other marker of its digit is labelled in its flash,
    and when the flash refitted with the new labels leaves it farther than the gate (``factor``
    times the gate for a confirmed point) from its marker (then the flash is fitted again
    without it).

    Returns
    -------
    HandLabels
        With ``points``, ``colours``, ``point_index``, ``positions``, ``fits``, ``rms``,
        ``members`` and ``unassigned`` updated; the number of labels added is
        ``(result.point_index >= 0).sum() - (labels.point_index >= 0).sum()``.
    """
    from dataclasses import replace

    from stillcap.body.hand import fit_hand

    pts = np.asarray(points, float)
    cols = np.asarray(colors).astype(str)
    unconfirmed = np.zeros(len(pts), bool) if unconfirmed is None else np.asarray(unconfirmed, bool)
    posed = [k for k in range(labels.n_flashes) if labels.fits[k] is not None]
    mcol = np.asarray(labels.marker_colors).astype(str)
    model = {k: labels.markerset.positions(labels.fits[k].pose) for k in posed}
    props = [(int(p), int(k), int(m)) for p, k, m in proposals]
    count = {}
    for p, _, _ in props:
        count[p] = count.get(p, 0) + 1
    pred = (np.array([model[k][m] for _, k, m in props]).reshape(-1, 3) if predicted is None
            else np.asarray(predicted, float).reshape(-1, 3))
    confirmed = np.zeros(len(pts), bool) if confirmed is None else np.asarray(confirmed, bool)
    idx = np.arange(len(mcol))
    pi = labels.point_index.copy()
    keep = []
    for (p, k, m), X0 in zip(props, pred):
        if count[p] > 1 or pi[k, m] >= 0 or p in pi:
            continue
        reach = gate_m * (factor if confirmed[p] else 1.0)
        if not np.linalg.norm(pts[p] - X0) <= reach:
            continue
        others = sum(int(np.sum((mcol == cols[p]) & (np.linalg.norm(model[q] - pts[p], axis=1) <= reach)
                                & ((idx != m) | (q != k)))) for q in posed)
        if others:
            continue  # another marker of its colour is as near: not unambiguous
        if np.linalg.norm(pts[p] - X0) > gate_m and not _wide_gate_safe(labels, pi, k, m, pts[p], cols[p]):
            continue
        keep.append((p, k, m))
    digits = _digit_markers(labels)
    fits = list(labels.fits)
    changed = set()
    for p, k, m in keep:
        pi[k, m] = p
        changed.add(k)
    for k in sorted(changed):
        for _ in range(3):
            new = [(p, kk, m) for p, kk, m in keep if kk == k and pi[k, m] == p]
            for p, _, m in new:  # alone on its digit, an unconfirmed point is untested
                dig = next((d for d in digits if m in d), None)  # None: a back-of-hand marker
                if unconfirmed[p] and dig is not None and (pi[k, dig] >= 0).sum() < 2:
                    pi[k, m] = -1
            pos = np.where((pi[k] >= 0)[:, None], pts[np.maximum(pi[k], 0)], np.nan)
            fits[k] = fit_hand(labels.skeleton, labels.markerset, pos, initial=fits[k].pose)
            bad = [m for p, _, m in new if pi[k, m] == p
                   and not fits[k].residuals[m] <= gate_m * (factor if confirmed[p] else 1.0)]
            if not bad:
                break
            pi[k, bad] = -1
        else:  # the last labels taken back: the flash fitted without them
            pos = np.where((pi[k] >= 0)[:, None], pts[np.maximum(pi[k], 0)], np.nan)
            fits[k] = fit_hand(labels.skeleton, labels.markerset, pos, initial=fits[k].pose)
    positions = np.where((pi >= 0)[..., None], pts[np.maximum(pi, 0)], np.nan)
    used = set(pi[pi >= 0].tolist()) | set(np.asarray(labels.deleted).tolist())
    unassigned = np.array([i for i in range(len(pts)) if i not in used and np.all(np.isfinite(pts[i]))], int)
    members = [np.array(sorted(set(pi[k][pi[k] >= 0].tolist()) | set(np.asarray(mem).tolist())), int)
               if labels.fits[k] is not None else np.asarray(mem, int) for k, mem in enumerate(labels.members)]
    rms = np.array([np.nan if f is None else f.rms for f in fits])
    return replace(labels, points=pts, colors=cols, point_index=pi, positions=positions, fits=fits, rms=rms,
                   members=members, unassigned=unassigned)



def digit_search(labels, points, colors, candidates, *, grid_gate_m: float, gate_m: float,
                 grid_step_deg: float = 15.0, min_markers: int = 2):
    """Labels proposed for points on digits whose fitted pose is a guess (issue 12).

    A posed flash's digit with few labelled markers has its joint angles from the fit's start,
    not from its own points, so :func:`predicted_missing` can put its other markers 30-130 mm
    from where they are (on the studio's other hands), far beyond any gate. Here the digit's
    whole range of motion is searched instead, as the first labelling pass does for a flash with
    a back-of-hand triplet: the flash's fitted root pose fixed, the best grid pose per digit
    (:func:`~stillcap.body.hand_grid.grid_match`, the digit's labelled points available with the
    candidates) and the flash fitted with the new labels. A digit's new labels are proposed only
    when the digit's grid labelling keeps every label the digit already has, at least
    ``min_markers`` of its markers are labelled so (two markers on one kinematic chain check each
    other: a stray point alone fits some angle of any digit) and the refitted hand puts every one
    of them within ``gate_m`` of its point. A candidate that two (flash, marker) proposals want is
    proposed for neither. The labeller's own tests follow
    (:func:`label_recovered`, with the refitted positions as the predictions).

    Parameters
    ----------
    labels : HandLabels
    points : array_like, shape (N', 3)
        ``labels.points`` with rows changed or appended for the candidates.
    colours : array_like of str, shape (N',)
    candidates : array_like of int
        Rows of ``points`` that may be labelled (unlabelled points not shared with labelled ones).
    grid_gate_m, gate_m : float
        The labeller's grid and assignment gates (m), already scaled to the hand.
    grid_step_deg : float
        Grid step of the digit search (degrees).
    min_markers : int
        Markers a digit needs labelled, old and new, for its new labels to be proposed.

    Returns
    -------
    proposals : list of (point, flash, marker)
    predicted : ndarray, shape (len(proposals), 3)
        The refitted hand's marker for each proposal (world, m).
    """
    from stillcap.body.hand import fit_hand

    pts = np.asarray(points, float)
    cols = np.asarray(colors).astype(str)
    cand = np.asarray(candidates, int)
    if pts.ndim != 2 or pts.shape[1] != 3 or cols.shape != (len(pts),):
        raise ValueError(f"points must have shape (N, 3) and colours (N,), got {pts.shape} and {cols.shape}")
    if len(cand) and (cand.min() < 0 or cand.max() >= len(pts)):
        raise ValueError(f"candidates must be rows of points (0..{len(pts) - 1})")
    out, pred = [], []
    if not len(cand):
        return out, np.zeros((0, 3))
    model = LabelModel(labels.skeleton, labels.markerset, grid_step_deg)
    pi = labels.point_index
    for k in range(labels.n_flashes):
        fit = labels.fits[k]
        if fit is None:
            continue
        own = pi[k][pi[k] >= 0]
        avail = np.zeros(len(pts), bool)
        avail[cand] = True
        avail[own] = True
        grid, _, _, _ = grid_match(model, fit.pose.root2world, pts, cols, avail, grid_gate_m, fit.angles_deg)
        tentative = {int(m): int(p) for m, p in enumerate(pi[k]) if p >= 0}
        new = {}
        for dig in model.digits:
            have = {int(m): tentative[int(m)] for m in dig.markers if int(m) in tentative}
            got = {int(m): grid[int(m)] for m in dig.markers if int(m) in grid}
            if any(got.get(m) != p for m, p in have.items()):
                continue  # the grid pose contradicts the digit's labels
            add = {m: p for m, p in got.items() if m not in have and p in cand}
            if add and len(have) + len(add) >= min_markers:
                new.update(add)
        if not new:
            continue
        pos = np.full((len(labels.marker_names), 3), np.nan)
        for m, p in {**tentative, **new}.items():
            pos[m] = pts[p]
        refit = fit_hand(labels.skeleton, labels.markerset, pos, initial=fit.pose)
        X = labels.markerset.positions(refit.pose)
        for dig in model.digits:
            add = [int(m) for m in dig.markers if int(m) in new]
            if add and all(refit.residuals[m] <= gate_m for m in add):
                for m in add:
                    out.append((new[m], k, m))
                    pred.append(X[m])
    wanted = {}
    for p, _, _ in out:
        wanted[p] = wanted.get(p, 0) + 1
    keep = [i for i, (p, _, _) in enumerate(out) if wanted[p] == 1]
    return [out[i] for i in keep], np.array([pred[i] for i in keep], float).reshape(-1, 3)
