"""Synthetic bead photos with known sub-pixel centres, for tests and benchmarks of the bead
detector (:mod:`stillcap.detect.circles`): shaded beads (matte spheres lit from the camera) on
dark limbs, anti-aliased at 8x (:func:`draw_beads`), and random puppet-like photos with their
truth (:func:`random_bead_scene`, :class:`BeadScene`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from stillcap._checks import as_array, as_rng

__all__ = ["BeadScene", "draw_beads", "random_bead_scene"]


@dataclass(eq=False)
class BeadScene:
    """A drawn bead photo with its ground truth (:func:`random_bead_scene`).

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), uint8
        BGR photo.
    centers : ndarray, shape (K, 2)
        True bead centres (x, y), pixels.
    radii : ndarray, shape (K,)
        True bead radii, pixels.
    labels : ndarray of int, shape (K,)
        Index of each bead's colour in the ``colors_rgb`` that drew it.
    colors_rgb : ndarray, shape (K, 3)
        Colour each bead was drawn with (after the lighting change), sRGB [0, 1].
    occluded : ndarray of float, shape (K,)
        Fraction of each bead's disc hidden by a limb in front of it.
    gain, white_balance : float, ndarray shape (3,)
        Lighting change applied (brightness factor, RGB channel factors).
    """

    image: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    labels: np.ndarray
    colors_rgb: np.ndarray
    occluded: np.ndarray
    gain: float = 1.0
    white_balance: np.ndarray = field(default_factory=lambda: np.ones(3))


_SS = 8  # supersampling factor of the drawings


def _patch_grid(cx, cy, R, shape):
    """Supersampled sample positions (1x pixel units) of a pixel-aligned box around a disc."""
    h, w = shape
    x0, x1 = max(0, int(np.floor(cx - R)) - 1), min(w, int(np.ceil(cx + R)) + 2)
    y0, y1 = max(0, int(np.floor(cy - R)) - 1), min(h, int(np.ceil(cy + R)) + 2)
    if x1 <= x0 or y1 <= y0:
        return None
    # Sample u of the 8x grid sits at (u + 0.5) / 8 - 0.5 in 1x pixel coordinates.
    xs = x0 + (np.arange((x1 - x0) * _SS) + 0.5) / _SS - 0.5
    ys = y0 + (np.arange((y1 - y0) * _SS) + 0.5) / _SS - 0.5
    return x0, x1, y0, y1, xs[None, :], ys[:, None]


def _down(a, ny, nx):
    """Block mean of a supersampled array down to (ny, nx[, C])."""
    return a.reshape(ny, _SS, nx, _SS, *a.shape[2:]).mean(axis=(1, 3))


def _over(canvas, y0, y1, x0, x1, alpha, color_premult):
    canvas[y0:y1, x0:x1] = canvas[y0:y1, x0:x1] * (1 - alpha[..., None]) + color_premult


def _shade(d, R, ambient, specular):
    """Brightness factor of a matte sphere lit from the camera, sRGB-encoded, at distance d."""
    cos = np.sqrt(np.clip(1 - (d / R) ** 2, 0, 1))
    lin = ambient + (1 - ambient) * cos
    return lin ** (1 / 2.2), specular * np.exp(-((d / (0.3 * R)) ** 2))


def _patch_norm(R, ambient):
    """Mean shading over the central 5x5 pixels: bead colours are scaled by its inverse, so
    that the thesis's 5x5 patch measures the colour asked for."""
    g = (np.arange(5 * _SS) + 0.5) / _SS - 2.5
    d = np.hypot(g[None, :], g[:, None])
    return float(_shade(d, R, ambient, 0.0)[0].mean())


def _draw_limb(canvas, p0, p1, width, grey):
    """A flat dark-grey thick segment (a limb of the black puppet), anti-aliased at 8x."""
    h, w = canvas.shape[:2]
    lo = np.floor(np.minimum(p0, p1) - width).astype(int)
    hi = np.ceil(np.maximum(p0, p1) + width).astype(int) + 1
    x0, y0 = max(0, lo[0]), max(0, lo[1])
    x1, y1 = min(w, hi[0]), min(h, hi[1])
    if x1 <= x0 or y1 <= y0:
        return
    big = np.zeros(((y1 - y0) * _SS, (x1 - x0) * _SS), np.uint8)
    # cv2.line with 3 fractional bits, in 8x pixel units: ((p - origin + 0.5) * 8 - 0.5) * 8.
    q = [tuple(int(round(((v - o + 0.5) * _SS - 0.5) * 8)) for v, o in zip(p, (x0, y0))) for p in (p0, p1)]
    cv2.line(big, q[0], q[1], 255, thickness=max(1, int(round(width * _SS))), lineType=cv2.LINE_8, shift=3)
    a = _down(big.astype(np.float32) / 255.0, y1 - y0, x1 - x0)
    _over(canvas, y0, y1, x0, x1, a, a[..., None] * np.asarray(grey, np.float32))


def draw_beads(centers, radii, colors_rgb, size=(480, 640), limbs_behind=(), limbs_front=(),
               background: float = 0.05, ambient: float = 0.15, specular: float = 0.0) -> np.ndarray:
    """Draw shaded beads (matte spheres lit from the camera) and limbs, anti-aliased at 8x.

    Each bead's colour is scaled so that the mean over its central 5x5 pixels equals the
    colour given (how the thesis measured its reference colours). Later beads cover earlier
    ones.

    Parameters
    ----------
    centers : array_like, shape (K, 2)
        Sub-pixel centres (x, y).
    radii : array_like, shape (K,)
        Pixels.
    colors_rgb : array_like, shape (K, 3)
        sRGB in [0, 1].
    size : (int, int)
        Image height and width.
    limbs_behind, limbs_front : sequence of (p0, p1, width, grey)
        Thick segments drawn before / after the beads: end points (x, y), width in pixels, grey
        level in [0, 1].
    background : float
        Grey level of the background, [0, 1].
    ambient, specular : float
        Shading: ambient share of the lighting, strength of a white highlight at the centre.

    Returns
    -------
    ndarray, shape (H, W, 3), float32
        Noise-free BGR image in [0, 1].
    """
    c = as_array(centers, (None, 2), "centers")
    r = as_array(radii, (len(c),), "radii")
    col = as_array(colors_rgb, (len(c), 3), "colors_rgb")
    h, w = int(size[0]), int(size[1])
    canvas = np.full((h, w, 3), background, np.float32)
    for p0, p1, width, grey in limbs_behind:
        _draw_limb(canvas, np.asarray(p0, float), np.asarray(p1, float), float(width), grey)
    for (cx, cy), R, rgb in zip(c, r, col):
        g = _patch_grid(cx, cy, R, (h, w))
        if g is None:
            continue
        x0, x1, y0, y1, xs, ys = g
        d = np.hypot(xs - cx, ys - cy)
        inside = (d <= R).astype(np.float32)
        shade, spec = _shade(d, R, ambient, specular)
        albedo = np.asarray(rgb, np.float32)[::-1] / _patch_norm(R, ambient)
        color = np.clip(shade[..., None] * albedo + spec[..., None], 0, 1) * inside[..., None]
        ny, nx = y1 - y0, x1 - x0
        _over(canvas, y0, y1, x0, x1, _down(inside, ny, nx), _down(color.astype(np.float32), ny, nx))
    for p0, p1, width, grey in limbs_front:
        _draw_limb(canvas, np.asarray(p0, float), np.asarray(p1, float), float(width), grey)
    return canvas


def _sensor(canvas, rng, blur, noise, jpeg):
    img = canvas
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img = img * 255.0 + rng.normal(0.0, noise, img.shape)
    img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if jpeg:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg)])
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return img


def random_bead_scene(colors_rgb, rng=None, size=(480, 640), radius_range=(5.0, 7.0), n_limbs: int = 8,
                      n_touching: int = 2, n_occluded: int = 1, brightness=(0.8, 1.2),
                      white_balance: float = 0.05, noise: float = 3.0, jpeg: int | None = 80,
                      blur: float = 0.5, specular: float = 0.05, limb_grey=(0.05, 0.14),
                      n_beads: int | None = None, margin: float = 20.0) -> BeadScene:
    """A random puppet-like photo: one bead per colour on dark limbs, with known truth.

    With ``n_beads`` only a random subset of the colours is drawn (markers hidden behind the
    puppet in a turntable view); ``labels`` says which.

    Dark grey limbs (thick segments, grey ``limb_grey``) criss-cross the frame; each bead sits on a
    limb; ``n_touching`` beads are placed touching (or overlapping by up to 1 px) another one;
    ``n_occluded`` beads are partly covered (10-35 % of the disc) by a limb in front. The
    light changes by a random brightness factor and a random per-channel white-balance factor
    (1 +- ``white_balance``); the sensor blurs, adds Gaussian noise and saves a JPEG.

    Parameters
    ----------
    colors_rgb : array_like, shape (K, 3)
        Bead colours at nominal light, sRGB [0, 1] (e.g. ``Palette.from_markerset(MarkerSet.puppet()).rgb``).
    rng : numpy.random.Generator or int, optional
    size : (int, int)
        Height, width.
    radius_range : (float, float)
        Bead radii are drawn uniformly from it, pixels.
    n_limbs, n_touching, n_occluded : int
    brightness : (float, float)
        Range of the brightness factor.
    white_balance : float
        Largest relative change of the red and blue channels.
    noise : float
        Standard deviation of the sensor noise, 8-bit units.
    jpeg : int or None
        JPEG quality, or None for no compression.
    blur : float
        Optical blur, Gaussian sigma in pixels.
    specular : float
        White highlight at the bead centre (flat paint: small).
    limb_grey : (float, float)
        Range of the limbs' grey level, [0, 1] (flat black paint under the LEDs: dark grey).
    n_beads : int, optional
        Number of beads drawn (a random subset of the colours); default all.
    margin : float
        Smallest distance of a bead centre from the image border, pixels.

    Returns
    -------
    BeadScene
    """
    rng = as_rng(rng)
    palette = as_array(colors_rgb, (None, 3), "colors_rgb")
    if n_beads is None:
        labels = np.arange(len(palette))
    else:
        if not 0 <= n_beads <= len(palette):
            raise ValueError(f"n_beads must lie in [0, {len(palette)}], got {n_beads}")
        labels = np.sort(rng.choice(len(palette), size=int(n_beads), replace=False))
    base = palette[labels]
    k = len(base)
    h, w = int(size[0]), int(size[1])
    r = rng.uniform(radius_range[0], radius_range[1], k)
    limbs = []
    for _ in range(max(1, n_limbs)):
        p0 = rng.uniform([margin, margin], [w - margin, h - margin])
        ang = rng.uniform(0, np.pi)
        length = rng.uniform(60, 220)
        p1 = np.clip(p0 + length * np.array([np.cos(ang), np.sin(ang)]), 0, [w - 1, h - 1])
        limbs.append((p0, p1, rng.uniform(8, 18), rng.uniform(*limb_grey)))
    centers = np.zeros((k, 2))
    touching = set()
    if k > 1:
        touching = set(rng.choice(np.arange(1, k), size=min(n_touching, k - 1), replace=False).tolist())
    for i in range(k):
        for _attempt in range(500):
            if i in touching:
                j = int(rng.integers(i))
                a = rng.uniform(0, 2 * np.pi)
                p = centers[j] + (r[i] + r[j] + rng.uniform(-1.0, 0.5)) * np.array([np.cos(a), np.sin(a)])
                others = np.delete(np.arange(i), j)
            else:
                p0, p1, width, _ = limbs[int(rng.integers(len(limbs)))]
                t = rng.uniform(0, 1)
                dvec = (p1 - p0) / max(np.linalg.norm(p1 - p0), 1e-9)
                p = p0 + t * (p1 - p0) + rng.uniform(-0.3, 0.3) * width * np.array([-dvec[1], dvec[0]])
                others = np.arange(i)
            if not (margin <= p[0] <= w - 1 - margin and margin <= p[1] <= h - 1 - margin):
                continue
            if len(others) and np.min(np.hypot(*(centers[others] - p).T) - r[others] - r[i]) < 4.0:
                continue
            centers[i] = p
            break
        else:
            centers[i] = rng.uniform([margin, margin], [w - 1 - margin, h - 1 - margin])
    gain = float(rng.uniform(*brightness))
    wb = np.array([1 + rng.uniform(-white_balance, white_balance), 1.0, 1 + rng.uniform(-white_balance, white_balance)])
    colors = np.clip(base * gain * wb, 0, 1)
    front = []
    occluded = np.zeros(k)
    candidates = [i for i in range(k) if i not in touching]
    for i in rng.permutation(candidates)[:n_occluded]:
        a = rng.uniform(0, 2 * np.pi)
        n_vec = np.array([np.cos(a), np.sin(a)])
        width = rng.uniform(8, 14)
        frac = rng.uniform(0.1, 0.35)
        # Distance from the centre to the limb's edge that covers ``frac`` of the disc.
        u = np.linspace(-1, 1, 2001)
        seg = np.cumsum(np.sqrt(1 - u**2))[::-1] / np.sqrt(1 - u**2).sum()
        hdist = u[np.argmin(np.abs(seg - frac))] * r[i]
        mid = centers[i] + (hdist + width / 2) * n_vec
        t_vec = np.array([-n_vec[1], n_vec[0]])
        front.append((mid - 40 * t_vec, mid + 40 * t_vec, width, rng.uniform(*limb_grey)))
    if front:
        # Hidden share of every disc (a front limb may cover more than the bead it was made for).
        g = (np.arange(16) + 0.5) / 16 * 2 - 1
        gx, gy = np.meshgrid(g, g)
        disc = np.stack([gx[gx**2 + gy**2 <= 1], gy[gx**2 + gy**2 <= 1]], axis=1)
        for i in range(k):
            pts = centers[i] + r[i] * disc
            hidden = np.zeros(len(pts), bool)
            for p0, p1, width, _ in front:
                v = p1 - p0
                t = np.clip((pts - p0) @ v / (v @ v), 0, 1)
                hidden |= np.hypot(*(pts - p0 - t[:, None] * v).T) <= width / 2
            occluded[i] = hidden.mean()
    canvas = draw_beads(centers, r, colors, (h, w), limbs, front, background=float(rng.uniform(0.02, 0.07)),
                        specular=specular)
    img = _sensor(canvas, rng, blur, noise, jpeg)
    return BeadScene(img, centers, r, labels, colors, occluded, gain, wb)
