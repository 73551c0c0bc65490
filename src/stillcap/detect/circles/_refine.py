"""Sub-pixel bead centres: the intensity-weighted centroid of each disc on the grey image,
iterated (:func:`refine_bead_centers`; :func:`refine_bead_centers_views` for several photos'
beads in one set of array operations)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from stillcap._checks import as_array
from stillcap.detect.circles._thesis import grey_image


def refine_bead_centers(image, centers, radii, iterations: int = 3, background=None,
                        local_bg: bool = True) -> np.ndarray:
    """Sub-pixel centres: intensity-weighted centroid of each disc on the grey image, iterated.

    Weights are ``grey - background`` (clipped at 0) over the pixels within ``radius + 1.5``
    of the current centre; the window then moves to the new centroid. For a symmetric bead
    that is unbiased (partly covered rim pixels weigh in proportion). Pixels nearer (relative
    to the radii) to a neighbouring circle are left out, so touching beads do not pull each
    other. Hand-written (vectorised over the circles' small windows): scikit-image's and
    OpenCV's moments need a label image, which touching beads on a limb do not have.

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
    centers : array_like, shape (N, 2)
        Start centres (x, y).
    radii : array_like, shape (N,)
        Pixels.
    iterations : int
    background : float, optional
        Grey level of the background; default the median of the image.
    local_bg : bool
        Subtract, per circle, the median grey of the ring from ``radius + 1`` to
        ``radius + 3.5`` (if brighter than ``background``): a limb under the bead then does not
        pull the centre towards the limb.

    Returns
    -------
    ndarray, shape (N, 2)
        A centre that would move by more than its radius (a false circle) keeps its start value.
    """
    img = np.asarray(image)
    # a float32 grey image (what find_circles passes) is only read here: no copy of it
    grey = img if img.ndim == 2 and img.dtype == np.float32 else grey_image(img)
    return refine_bead_centers_views([grey], [centers], [radii], iterations, [background], local_bg)[0]


def refine_bead_centers_views(greys: Sequence[np.ndarray], centers: Sequence, radii: Sequence,
                              iterations: int = 3, backgrounds: Sequence | None = None,
                              local_bg: bool = True) -> list[np.ndarray]:
    """:func:`refine_bead_centers` of several photos' circles at once: each photo's centres are
    those :func:`refine_bead_centers` gives on it alone (a photo stops iterating when its own
    centres have settled; neighbours are looked for in the same photo only), from one set of
    array operations for all photos' circles (the puppet pipeline refines its 12 photos' beads
    together: the per-call overhead of the small arrays is most of the cost).

    Parameters
    ----------
    greys : sequence of n_views arrays, each shape (H, W)
        Grey images (:func:`~stillcap.detect.circles.grey_image`; float32 ones are not copied).
    centers : sequence of n_views array_like, each shape (N_k, 2)
    radii : sequence of n_views array_like, each shape (N_k,)
    iterations : int
    backgrounds : sequence of n_views floats or None, optional
        Each photo's background grey level (None: the median of its grey image).
    local_bg : bool
        As :func:`refine_bead_centers`'s.

    Returns
    -------
    list of n_views ndarray, shape (N_k, 2)
    """
    nv = len(greys)
    if len(centers) != nv or len(radii) != nv or (backgrounds is not None and len(backgrounds) != nv):
        raise ValueError(f"need one centre array, radius array and background per grey image ({nv}), got "
                         f"{len(centers)}, {len(radii)} and {nv if backgrounds is None else len(backgrounds)}")
    # float32 grey images are only read (what find_circles passes); others as grey_image makes them
    gs = [g if g.ndim == 2 and g.dtype == np.float32 else grey_image(g) for g in map(np.asarray, greys)]
    cs = [as_array(c, (None, 2), "centers").copy() for c in centers]
    rs = [as_array(r, (len(c),), "radii") for c, r in zip(cs, radii)]
    out = [c for c in cs]
    # Photos whose largest radius gives the same window size, and whose grey images have the
    # same type, are refined together (the window size sets the order of the sums, the type
    # the precision of the medians: the result must be each photo's own)
    groups: dict[tuple, list[int]] = {}
    for k in range(nv):
        if len(cs[k]):
            groups.setdefault((int(np.ceil(rs[k].max() + 3.5)), gs[k].dtype.str), []).append(k)
    for (half, _), views in groups.items():
        bgs = []
        for k in views:
            b = None if backgrounds is None else backgrounds[k]
            bgs.append(float(np.median(gs[k])) if b is None else float(b))
        res = _refine_group([gs[k] for k in views], [cs[k] for k in views], [rs[k] for k in views], bgs, half,
                            iterations, local_bg)
        for k, c in zip(views, res):
            out[k] = c
    return out


def _refine_group(greys, centers, radii, bgs, half, iterations, local_bg):
    """The iterations of :func:`refine_bead_centers_views` for photos sharing the window
    half-size ``half`` (every photo at least one circle)."""
    counts = np.array([len(c) for c in centers])
    view = np.repeat(np.arange(len(greys)), counts)  # the photo of every circle
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    c = np.concatenate(centers)
    r = np.concatenate(radii)
    bg = np.repeat(np.asarray(bgs, float), counts)
    h = np.repeat([g.shape[0] for g in greys], counts)
    w = np.repeat([g.shape[1] for g in greys], counts)
    n = len(c)
    # All circles at once over one window size (the loop over circles cost ~0.5 ms each):
    # pixels (xs, ys) of a (S x S) window per circle, masked to the image; every mask below
    # is the per-circle one of the plain loop (own disc, power-diagram split, ring).
    off = np.arange(-half, half + 2)  # covers floor(x - B) .. ceil(x + B) for every circle
    S = len(off)
    idx = np.arange(n)
    # the pairs of distinct circles of one photo (neighbours are looked for in the circle's own
    # photo), row-major as np.nonzero of a photo's pair matrix lists them
    qi, qj = [], []
    for s0, m in zip(starts, counts):
        a, b = np.divmod(np.arange(m * m), m)
        qi.append(s0 + a[a != b])
        qj.append(s0 + b[a != b])
    qi, qj = (qi[0], qj[0]) if len(qi) == 1 else (np.concatenate(qi), np.concatenate(qj))
    # every S x S window of each grey image as a zero-copy view: the windows inside the image
    # are gathered per circle (~8x faster than indexing each pixel of each window; the few that
    # cross the border are read with clipped indices, i.e. the replicated border)
    gc = [np.ascontiguousarray(g) for g in greys]
    windows = [np.lib.stride_tricks.as_strided(g, (g.shape[0] - S + 1, g.shape[1] - S + 1, S, S), g.strides * 2,
                                               writeable=False) if g.shape[0] >= S and g.shape[1] >= S else None
               for g in gc]
    dtype = np.result_type(*gc)
    active = np.ones(len(greys), bool)  # photos still iterating
    cell_d = np.hypot(off[:, None] - 0.5, off[None, :] - 0.5).ravel()
    cells = np.flatnonzero((cell_d + 0.75 > r.min() + 1.0) & (cell_d - 0.75 <= r.max() + 3.5))
    for _ in range(max(1, iterations)):
        base = np.floor(c).astype(int)  # (n, 2)
        xs = (base[:, 0, None] + off[None])[:, None, :]  # (n, 1, S)
        ys = (base[:, 1, None] + off[None])[:, :, None]  # (n, S, 1)
        wy, wx = base[:, 1] - half, base[:, 0] - half  # window corners
        whole = (wy >= 0) & (wx >= 0) & (wy <= h - S) & (wx <= w - S)
        patch = np.empty((n, S, S), dtype)
        for k, (g, win) in enumerate(zip(gc, windows)):
            sl = slice(starts[k], starts[k] + counts[k])
            if win is None:
                whole[sl] = False
            wk = whole[sl]
            if wk.all():
                patch[sl] = win[wy[sl], wx[sl]]
                continue
            p = patch[sl]
            if wk.any():
                p[wk] = win[wy[sl][wk], wx[sl][wk]]
            o = ~wk
            p[o] = g[np.minimum(np.maximum(ys[sl][o], 0), g.shape[0] - 1),
                     np.minimum(np.maximum(xs[sl][o], 0), g.shape[1] - 1)]
        valid = None if whole.all() else ((xs >= 0) & (xs < w[:, None, None])) & ((ys >= 0) & (ys < h[:, None, None]))
        # squared distances compared with squared radii (np.hypot over every window pixel cost
        # as much as the rest of the iteration)
        dx, dy = xs - c[:, 0, None, None], ys - c[:, 1, None, None]
        d2_own = dx * dx + dy * dy
        R = (r + 1.5)[:, None, None]
        inside = d2_own <= R * R
        if local_bg:
            r1, r2 = (r + 1.0)[:, None, None], R + 2.0
            ring = (d2_own > r1 * r1) & (d2_own <= r2 * r2)
        if valid is not None:
            inside &= valid
            if local_bg:
                ring &= valid
        d = c[qi] - c[qj]
        near = np.hypot(d[:, 0], d[:, 1]) < (r[qj] + r[qi] + 3.0)
        pi, pj = qi[near], qj[near]  # pairs (circle, neighbour): few
        if len(pi):
            ex, ey = xs[pi] - c[pj, 0, None, None], ys[pi] - c[pj, 1, None, None]
            d2_j = ex * ex + ey * ey
            # power-diagram split between neighbouring circles (touching beads):
            # d_own / r_own <= d_j / r_j, squared
            np.logical_and.at(inside, pi, d2_own[pi] * (r[pj] ** 2)[:, None, None] <= d2_j * (r[pi] ** 2)[:, None, None])
            if local_bg:
                rj1 = (r[pj] + 1.0)[:, None, None]
                np.logical_and.at(ring, pi, d2_j > rj1 * rj1)
        if local_bg:
            # local background: median of the ring just outside the bead (a limb under it then
            # weighs nothing), never below the global background; medians of the masked rows
            # by sorting (non-members last) and picking the middle of each row's count
            k = ring.reshape(n, -1).sum(axis=1)
            # only the window cells that can be in some circle's ring are sorted (a centre lies
            # in [0, 1) px of its window's offset 0 cell on each axis, so a cell at offset o is
            # within 0.71 px of |o - 0.5| from it): the same members, about half the cells
            srt = np.sort(np.where(ring.reshape(n, -1)[:, cells], patch.reshape(n, -1)[:, cells], np.inf), axis=1)
            lo_, hi_ = np.maximum((k - 1) // 2, 0), np.maximum(k // 2, 0)
            med = 0.5 * (srt[idx, lo_] + srt[idx, hi_])
            # in the grey image's precision, as one photo's scalar background was (NumPy's
            # scalar promotion): float32 for a float32 grey image
            bgm = bg.astype(med.dtype)
            b = np.where(k > 0, np.maximum(bgm, med), bgm)
        else:
            b = bg
        # np.clip(patch - b, 0, None) * inside, the same values with cheaper calls
        wgt = np.where(inside, np.maximum(patch - b[:, None, None], 0), 0)
        s_ = wgt.sum(axis=(1, 2))
        new = c.copy()
        ok = s_ > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            cx = (wgt * xs).sum(axis=(1, 2)) / s_
            cy = (wgt * ys).sum(axis=(1, 2)) / s_
        new[ok] = np.stack([cx, cy], axis=1)[ok]
        moved = np.hypot(*(new - c).T)
        # A refinement that walks away (a false circle on a limb) is undone.
        bad = moved > r
        new[bad] = c[bad]
        # photos that stopped keep their centres; a photo stops once its centres have settled
        c = new if active.all() else np.where(active[view][:, None], new, c)
        active &= ~(np.maximum.reduceat(moved, starts) < 1e-3)
        if not active.any():
            break
    return [c] if len(greys) == 1 else [a.copy() for a in np.split(c, starts[1:])]
