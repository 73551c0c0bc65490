"""Sub-pixel bead centres: the intensity-weighted centroid of each disc on the grey image,
iterated (:func:`refine_bead_centers`)."""

from __future__ import annotations

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
    c = as_array(centers, (None, 2), "centers").copy()
    r = as_array(radii, (len(c),), "radii")
    if len(c) == 0:
        return c
    bg = float(np.median(grey)) if background is None else float(background)
    h, w = grey.shape
    n = len(c)
    # All circles at once over one window size (the loop over circles cost ~0.5 ms each):
    # pixels (xs, ys) of a (S x S) window per circle, masked to the image; every mask below
    # is the per-circle one of the plain loop (own disc, power-diagram split, ring).
    half = int(np.ceil(r.max() + 3.5))
    off = np.arange(-half, half + 2)  # covers floor(x - B) .. ceil(x + B) for every circle
    S = len(off)
    idx = np.arange(n)
    # every S x S window of the grey image as a zero-copy view: the windows inside the image are
    # gathered per circle (~8x faster than indexing each pixel of each window; the few that
    # cross the border are read with clipped indices, i.e. the replicated border)
    g = np.ascontiguousarray(grey)
    windows = (np.lib.stride_tricks.as_strided(g, (h - S + 1, w - S + 1, S, S), g.strides * 2, writeable=False)
               if h >= S and w >= S else None)
    for _ in range(max(1, iterations)):
        base = np.floor(c).astype(int)  # (n, 2)
        xs = (base[:, 0, None] + off[None])[:, None, :]  # (n, 1, S)
        ys = (base[:, 1, None] + off[None])[:, :, None]  # (n, S, 1)
        wy, wx = base[:, 1] - half, base[:, 0] - half  # window corners
        whole = (wy >= 0) & (wx >= 0) & (wy <= h - S) & (wx <= w - S) if windows is not None else np.zeros(n, bool)
        valid = None if whole.all() else ((xs >= 0) & (xs < w)) & ((ys >= 0) & (ys < h))  # None: all pixels
        if valid is None:
            patch = windows[wy, wx]  # (n, S, S)
        else:
            patch = np.empty((n, S, S), g.dtype)
            patch[whole] = windows[wy[whole], wx[whole]] if whole.any() else 0
            o = ~whole
            patch[o] = grey[np.clip(ys[o], 0, h - 1), np.clip(xs[o], 0, w - 1)]
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
        near = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1)) < (r[None] + r[:, None] + 3.0)
        near[idx, idx] = False
        pi, pj = np.nonzero(near)  # pairs (circle, neighbour): few
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
            srt = np.sort(np.where(ring, patch, np.inf).reshape(n, -1), axis=1)
            lo_, hi_ = np.maximum((k - 1) // 2, 0), np.maximum(k // 2, 0)
            med = 0.5 * (srt[idx, lo_] + srt[idx, hi_])
            b = np.where(k > 0, np.maximum(bg, med), bg)
        else:
            b = np.full(n, bg)
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
        c = new
        if moved.max(initial=0) < 1e-3:
            break
    return c
