"""The hand model's pieces the glove labelling works with (:mod:`stillcap.body.hand_label`,
:mod:`stillcap.body.hand_label_fill`): per-digit grids of poses precomputed in the hand frame,
back-of-hand triplets, the best grid pose per digit for a root pose, and the optimal assignment
of points to predicted markers (``docs/hand-labelling.md`` tells the method)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from stillcap.body.hand import BACK_MARKERS, DIGITS, fit_hand, marker_colors
from stillcap.body.kinematics import rigid_alignment
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Pose, Skeleton

__all__ = ["REACH_M", "Digit", "LabelModel", "assign_points", "back_triplets", "fit_labels", "grid_match",
           "label_flash", "root_pose"]

#: Points farther than this from a hand's root cannot belong to it (m; the hand is 0.19 m long).
REACH_M = 0.30
#: Log-likelihood of a marker the grid pose puts near no point of its colour (a hit at the
#: gate scores -2): an unseen marker is less likely than a seen one.
_LOG_MISS = -np.log(100.0)


@dataclass
class Digit:
    name: str
    chain: list            # joint indices, parents first
    markers: np.ndarray    # marker indices on the digit
    grid: np.ndarray       # (G, len(chain), 3) angles, degrees
    local: np.ndarray      # (G, len(markers), 3) marker positions in the root frame


class LabelModel:
    """The hand model's precomputed pieces for labelling."""

    def __init__(self, skeleton: Skeleton, markerset: MarkerSet, step_deg: float):
        self.skeleton, self.markerset = skeleton, markerset
        self.frames = markerset.bone_frames(skeleton)
        self.colors = np.asarray(marker_colors(markerset))
        self.back = np.array([markerset.index(n) for n in BACK_MARKERS])
        if np.any(self.frames[self.back] != skeleton.root):
            raise ValueError(f"the back-of-hand markers {list(BACK_MARKERS)} must ride on the root joint")
        if len(set(self.colors[self.back])) != 3:
            raise ValueError("the back-of-hand markers must have three different colours")
        self.back_model = markerset.offsets[self.back]
        self.digits = []
        names = skeleton.names
        for d in DIGITS:
            chain = [i for i in skeleton.depth_first if names[i].split("-")[0] == d]
            mk = np.flatnonzero(np.isin(self.frames, chain))
            if not chain or not len(mk):
                continue
            grid = self._grid(chain, step_deg)
            dig = Digit(d, chain, mk, grid, np.empty(0))
            dig.local = self.digit_markers(dig, grid)
            self.digits.append(dig)

    def _grid(self, chain, step_deg):
        lim = self.skeleton.limits_deg
        axes = []
        for i in chain:
            for a in range(3):
                lo, hi = lim[i, a]
                if np.isnan(lo):
                    lo, hi = -180.0, 180.0 - step_deg
                n = 1 if hi <= lo else int(np.ceil((hi - lo) / step_deg)) + 1
                axes.append(np.linspace(lo, hi, n))
        mesh = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(chain), 3)
        return mesh

    def digit_markers(self, dig: Digit, angles: np.ndarray) -> np.ndarray:
        """Marker positions of a digit in the root frame for angles (G, len(chain), 3) degrees."""
        sk = self.skeleton
        g = len(angles)
        local = Rotation.from_euler("XYZ", angles.reshape(-1, 3), degrees=True).as_matrix().reshape(g, -1, 3, 3)
        R, t = {}, {}
        for k, i in enumerate(dig.chain):  # vectorised forward kinematics over the grid
            p = sk.parents[i]
            if p == sk.root:
                R[i], t[i] = local[:, k], np.broadcast_to(sk.offsets[i], (g, 3))
            else:
                R[i] = R[p] @ local[:, k]
                t[i] = t[p] + R[p] @ sk.offsets[i]
        out = np.empty((g, len(dig.markers), 3))
        for k, m in enumerate(dig.markers):
            f = self.frames[m]
            out[:, k] = np.einsum("gij,j->gi", R[f], self.markerset.offsets[m]) + t[f]
        return out


def back_triplets(points, colors, avail, model: LabelModel, tol, size_range=None):
    """Candidate back-of-hand triplets: point indices (K, 3) in BACK_MARKERS order, and the size
    of each relative to the model (K,).

    ``size_range`` None: the sides must match the model's within ``tol`` (size 1). Given
    ``(lo, hi)``: the triangle may be the model's scaled by any size in the range (least-squares
    size from the three sides), each side within ``tol`` times the size: a hand larger or
    smaller than the model is found all the same.
    """
    bm = model.back_model
    pairs = ((0, 1), (0, 2), (1, 2))
    D = np.array([np.linalg.norm(bm[a] - bm[b]) for a, b in pairs])
    lo, hi = (1.0, 1.0) if size_range is None else (float(size_range[0]), float(size_range[1]))
    idx = [np.flatnonzero(avail & (colors == model.colors[b])) for b in model.back]
    out, sizes = [], []
    for i in idx[0]:
        d1 = np.linalg.norm(points[idx[1]] - points[i], axis=1)
        d2 = np.linalg.norm(points[idx[2]] - points[i], axis=1)
        js = idx[1][(d1 > lo * D[0] - tol * hi) & (d1 < hi * D[0] + tol * hi)]
        ks = idx[2][(d2 > lo * D[1] - tol * hi) & (d2 < hi * D[1] + tol * hi)]
        for j in js:
            for k in ks:
                d = np.array([np.linalg.norm(points[j] - points[i]), np.linalg.norm(points[k] - points[i]),
                              np.linalg.norm(points[j] - points[k])])
                s = 1.0 if size_range is None else float(np.clip(d @ D / (D @ D), lo, hi))
                if np.all(np.abs(d - s * D) < tol * s):
                    out.append((i, j, k))
                    sizes.append(s)
    return np.array(out, int).reshape(-1, 3), np.array(sizes, float)


def root_pose(model: LabelModel, points, triplet, scale: float = 1.0) -> np.ndarray:
    return rigid_alignment(scale * model.back_model, points[triplet]).model2world


def grid_match(model: LabelModel, r2w, points, colors, avail, gate, prior=None, scale: float = 1.0):
    """Best grid pose per digit for a root pose: ``(labels {marker: point}, angles (n_joints, 3),
    n matched digit markers, cost)``; ``scale``: the hand is the model scaled by it (the gate too)."""
    gate = gate * scale
    R, t = r2w[:3, :3], r2w[:3, 3]
    near = avail & (np.linalg.norm(points - t, axis=1) < REACH_M * scale)
    trees = {}
    for c in np.unique(model.colors):
        sel = np.flatnonzero(near & (colors == c))
        trees[c] = (cKDTree(points[sel]), sel) if len(sel) else None
    labels, angles, n, cost = {}, np.zeros((model.skeleton.n_joints, 3)), 0, 0.0
    for dig in model.digits:
        grid, local = dig.grid, dig.local
        if prior is not None:  # the neighbouring flash's pose competes with the grid
            pa = prior[dig.chain][None]
            grid = np.concatenate([grid, pa])
            local = np.concatenate([local, model.digit_markers(dig, pa)])
        world = (scale * local) @ R.T + t
        logw = np.zeros(len(grid))
        hits = np.full((len(grid), len(dig.markers)), -1)
        dists = np.full((len(grid), len(dig.markers)), np.inf)
        for k, m in enumerate(dig.markers):
            tr = trees[model.colors[m]]
            if tr is None:
                logw += _LOG_MISS
                continue
            d, j = tr[0].query(world[:, k], distance_upper_bound=gate)
            ok = np.isfinite(d)
            hits[ok, k] = tr[1][j[ok]]
            dists[:, k] = d
            logw += np.where(ok, -0.5 * (np.where(ok, d, 0) / (0.5 * gate)) ** 2, _LOG_MISS)
        # choose the labelling, not the grid pose: the labelling with the most evidence (the sum
        # of the grid poses' likelihoods that give it, a uniform prior over the angles within
        # the limits). A lone yellow point on the ring finger fits its PIP marker for a whole
        # range of PIP and DIP angles but its nail marker for few: it is the PIP.
        uniq, inv = np.unique(hits, axis=0, return_inverse=True)
        inv = inv.ravel()
        w = np.exp(logw - logw.max())
        ev = np.bincount(inv, weights=w, minlength=len(uniq))
        g = int(np.argmax(ev))
        members = np.flatnonzero(inv == g)
        b = int(members[np.argmax(logw[members])])
        angles[dig.chain] = grid[b]
        cost -= float(logw[b])
        row, dr = hits[b], dists[b]
        for k in np.argsort(dr):  # a point claimed twice within the digit goes to the nearer marker
            if row[k] >= 0 and row[k] not in labels.values():
                labels[int(dig.markers[k])] = int(row[k])
                n += 1
    return labels, angles, n, cost


def assign_points(model: LabelModel, predicted, points, colors, avail, gate, fixed):
    """Optimal assignment of points to predicted markers (colour a hard constraint, a dummy
    column per marker at the gate's cost); ``fixed`` {marker: point} are kept."""
    m = len(predicted)
    cand = np.flatnonzero(avail)
    cand = cand[np.min(np.linalg.norm(points[cand][:, None] - predicted[None], axis=-1), axis=1) < gate]
    cand = np.setdiff1d(cand, list(fixed.values()))
    rows = np.array([i for i in range(m) if i not in fixed], int)
    big = 1e6
    d2 = np.sum((predicted[rows][:, None] - points[cand][None]) ** 2, axis=-1)
    ok = (model.colors[rows][:, None] == colors[cand][None]) & (d2 < gate ** 2)
    cost = np.concatenate([np.where(ok, d2, big), np.where(np.eye(len(rows), dtype=bool), gate ** 2, big)], axis=1)
    r, c = linear_sum_assignment(cost)
    out = dict(fixed)
    for i, j in zip(r, c):
        if j < len(cand) and cost[i, j] < big:
            out[int(rows[i])] = int(cand[j])
    return out


def fit_labels(model: LabelModel, points, labels, initial: Pose):
    pos = np.full((len(model.markerset), 3), np.nan)
    for mk, p in labels.items():
        pos[mk] = points[p]
    return fit_hand(model.skeleton, model.markerset, pos, initial=initial), pos


def label_flash(model, points, colors, avail, triplet, prior_angles, grid_gate, gate, max_iter=4):
    """Labels and fit of one hand from its back-of-hand triplet."""
    r2w = root_pose(model, points, triplet)
    labels, angles, _, _ = grid_match(model, r2w, points, colors, avail, grid_gate, prior_angles)
    fixed = {int(b): int(p) for b, p in zip(model.back, triplet)}
    labels = {**{k: v for k, v in labels.items() if v not in fixed.values()}, **fixed}
    initial = Pose(model.skeleton, np.eye(4), Rotation.from_euler("XYZ", angles, degrees=True).as_matrix())
    fit, pos = fit_labels(model, points, labels, initial)
    for _ in range(max_iter):
        pred = model.markerset.positions(fit.pose)
        new = assign_points(model, pred, points, colors, avail, gate, fixed)
        if new == labels:
            break
        labels = new
        fit, pos = fit_labels(model, points, labels, fit.pose)
    return labels, fit, pos
