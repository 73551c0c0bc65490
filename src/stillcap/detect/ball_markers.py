"""Markers painted on the ball, found inside each ball image (seed section 4.1 and 4.4).

The seed's ball carries 12 markers of 4 types told apart by colour and shape: red square, blue
ring, green triangle, black circle (a disc). Inside each ball image (a disc of known centre and
radius, from :mod:`stillcap.detect.ball`) this module

1. classifies every pixel by colour against a configurable palette: chromatic types by hue and
   saturation (HSV), which do not change with the shading across the ball; achromatic dark
   types (black) by darkness relative to the local ball brightness (a morphological closing of
   the brightness that fills the markers in), and only where the ball is lit, so the dark side
   of a half moon is not one big black marker;
2. keeps connected regions above a minimum size (``cv2.connectedComponentsWithStats``);
3. measures each region's shape with affine-invariant features, since a marker away from the
   ball's centre is foreshortened (seen obliquely, a square becomes a parallelogram, a disc an
   ellipse): a hole makes a ring; otherwise the region is whitened by its second moments (which
   maps any parallelogram to a square and any ellipse to a circle) and the spread of its
   whitened outline radii tells disc (1.0), square (1.41) and triangle (2.0) apart;
4. returns each marker's centroid (soft-membership weighted, sub-pixel), type, area, measured
   shape and a confidence, with flags for markers near the limb or too foreshortened to trust.

The type comes from the colour; the shape confirms it (or decides between palette entries of
the same colour). Centroids are raw pixels ``(x, y)`` of the photo (OpenCV convention); the
centroid of a foreshortened marker is the centre of its image area, which lies slightly off the
projection of the marker's centre on the sphere (a fraction of a pixel for the seed's marker
size except right at the limb).

Steps 3 and 4 for one region are in :mod:`stillcap.detect._marker_measure`, the palette's types and
the flags in :mod:`stillcap.detect._marker_types` (their public names re-exported here).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from stillcap._checks import as_array
from stillcap._numeric import median_columns
from stillcap.detect import _marker_chroma as _mc
from stillcap.detect._marker_chroma import _hue_distance
from stillcap.detect._ball_light import crop_light, light_disc, terminator_weights
from stillcap.detect._blur_shift import _fit_shading, _shading_at, shading_blur_correction, shading_blur_shift
from stillcap.detect._marker_measure import NOISE_MARGIN, _BOX3, _measure, classify_shape  # noqa: F401 (re-exported)
from stillcap.detect._marker_noise import _brightness_bins, _noise_by_brightness, _robust_ceiling
from stillcap.detect._marker_types import BASEBALL_MARKER_TYPES, SHAPES, MarkerFlag, MarkerType
from stillcap.detect.ball._hough import _percentile
from stillcap.response import Response

__all__ = ["MarkerType", "MarkerFlag", "BallMarkers", "BASEBALL_MARKER_TYPES", "SHAPES",
           "detect_ball_markers", "classify_shape", "marker_color_class", "ball_white_balance"]


@functools.lru_cache(maxsize=64)
def _ellipse_kernel(k: int) -> np.ndarray:
    """``cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))``, once per size (read-only)."""
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    ker.flags.writeable = False
    return ker


@dataclass
class BallMarkers:
    """Markers found in one photo.

    Attributes
    ----------
    centers : ndarray, shape (N, 2)
        Marker centroids, raw pixels ``(x, y)``.
    types : ndarray of str (object), shape (N,)
        Palette type names.
    shapes : ndarray of str (object), shape (N,)
        Measured shapes ("disc", "ring", "square", "triangle" or "unknown").
    areas : ndarray, shape (N,)
        Region areas in px^2.
    confidences : ndarray, shape (N,)
        0-1: colour match x shape agreement x foreshortening.
    aspects : ndarray, shape (N,)
        Minor/major axis ratio of the region (1 = seen face on).
    ball_index : ndarray of int, shape (N,)
        Index of the ball (in the ``centers`` given) each marker belongs to.
    flags : ndarray of int, shape (N,)
        :class:`MarkerFlag` bits.
    blur_error_px : ndarray, shape (N, 2), optional
        Each centroid's blur correction's own 1-sigma error (:func:`~stillcap.detect._blur_shift.shading_blur_correction`: the
        correction times ``min(1, s |grad log S|)``), px, common to every photo of a pose (zeros
        without a correction).
    light_view : ndarray, shape (N, 3), optional
        The light's direction at each marker's ball as its shading shows it
        (:func:`~stillcap.detect._ball_light.fit_ball_light`), unit, in the ball's view frame (x, y
        the image's axes, z the line of sight through the ball's centre, away from the camera;
        :func:`~stillcap.detect._ball_light.view_to_camera` turns it into the camera's); NaN where
        the ball's shading gave none.
    light_sigma_deg : ndarray, shape (N,), optional
        That direction's expected (RMS) angular error from its fit, deg (NaN with it).
    centroid_sigma_px : ndarray, shape (N,), optional
        Each centroid's standard error from its own photo's noise, px per axis
        (:func:`~stillcap.detect._marker_noise.centroid_sigma_px`: the robust spread of the
        leather's residual against the ball's white around the marker, through the centroid's
        weights); NaN where unknown (a marker weighed against the light's terminator model).
    """

    centers: np.ndarray
    types: np.ndarray
    shapes: np.ndarray
    areas: np.ndarray
    confidences: np.ndarray
    aspects: np.ndarray
    ball_index: np.ndarray
    flags: np.ndarray
    blur_error_px: np.ndarray = None
    light_view: np.ndarray = None
    light_sigma_deg: np.ndarray = None
    centroid_sigma_px: np.ndarray = None

    def __post_init__(self):
        if self.blur_error_px is None:
            self.blur_error_px = np.zeros((len(self.centers), 2))
        if self.light_view is None:
            self.light_view = np.full((len(self.centers), 3), np.nan)
        if self.light_sigma_deg is None:
            self.light_sigma_deg = np.full(len(self.centers), np.nan)
        if self.centroid_sigma_px is None:
            self.centroid_sigma_px = np.full(len(self.centers), np.nan)

    def __len__(self) -> int:
        return len(self.centers)

    @classmethod
    def empty(cls) -> BallMarkers:
        return cls(np.zeros((0, 2)), np.zeros(0, object), np.zeros(0, object), np.zeros(0), np.zeros(0),
                   np.zeros(0), np.zeros(0, int), np.zeros(0, int))

    def select(self, keep) -> BallMarkers:
        """The markers where ``keep`` (bool (N,) or indices) holds."""
        k = np.asarray(keep)
        return BallMarkers(self.centers[k], self.types[k], self.shapes[k], self.areas[k], self.confidences[k],
                           self.aspects[k], self.ball_index[k], self.flags[k], self.blur_error_px[k],
                           self.light_view[k], self.light_sigma_deg[k], self.centroid_sigma_px[k])

    def of_ball(self, i: int) -> BallMarkers:
        """The markers of ball ``i``."""
        return self.select(self.ball_index == i)


# --------------------------------------------------------------------------------------------
# detection
# --------------------------------------------------------------------------------------------
def _types(types) -> list[MarkerType]:
    if isinstance(types, Mapping):
        out = []
        for name, v in types.items():
            if isinstance(v, MarkerType):
                out.append(v)
            else:
                try:
                    color, shape = v
                except (TypeError, ValueError):
                    raise ValueError(f"palette entry {name!r} must be (color_bgr, shape), got {v!r}") from None
                out.append(MarkerType(str(name), color, shape))
        types = out
    types = list(types)
    if not types or not all(isinstance(t, MarkerType) for t in types):
        raise ValueError("types must be a non-empty sequence of MarkerType or a dict name -> (color_bgr, shape)")
    return types


def _hsv(bgr) -> tuple[float, float, float]:
    c = np.asarray(bgr, np.float32).reshape(1, 1, 3) / 255.0
    h, s, v = cv2.cvtColor(c, cv2.COLOR_BGR2HSV).reshape(3)
    return float(h), float(s), float(v)


def marker_color_class(color_bgr) -> tuple:
    """How the detector finds a paint colour (BGR 0-255, as it looks fully lit): ``("chromatic",
    hue_deg)`` (saturation >= 0.3: by hue), ``("dark", None)`` (value < 0.35: by darkness
    relative to the ball) or ``(None, None)`` (white, grey: not told from a white ball)."""
    h, s, v = _hsv(color_bgr)
    if s >= 0.3:
        return "chromatic", h
    if v < 0.35:
        return "dark", None
    return None, None


def _hull_mask(mask: np.ndarray) -> np.ndarray:
    """The filled convex hull (uint8 0/1) of the pixels of a boolean mask (>= 1 pixel).

    The hull's vertices are among each row's first and last pixels, so the hull is taken of
    those: the same polygon as of all the pixels (``cv2.findNonZero``), at a fraction of the cost.
    """
    ys = np.flatnonzero(mask.any(axis=1))
    m = mask[ys]
    ends = np.empty((2 * len(ys), 2), np.int32)
    ends[0::2, 0] = m.argmax(axis=1)
    ends[1::2, 0] = m.shape[1] - 1 - m[:, ::-1].argmax(axis=1)
    ends[:, 1] = np.repeat(ys, 2)
    out = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(out, cv2.convexHull(ends), 1)
    return out


def ball_white_balance(image, centers, radii_px, inner_fraction: float = 0.85, lit_share: float = 0.6,
                       clip: float = 250.0, min_pixels: int = 30) -> np.ndarray:
    """The photo's white balance measured on the balls: BGR gains (largest 1) of the ball's lit
    leather, as the photo encodes it.

    Model: the leather is white (near grey: a colour cast of the camera or the light is the
    only reason its lit pixels are coloured), and a cast is a gain per channel in linear light,
    which a power-law response keeps a gain per channel in the encoded values (nearly so for
    sRGB and tone curves over the lit pixels used). The lit leather is the ball's pixels within
    ``inner_fraction`` of its radius whose brightness (their largest channel) reaches
    ``lit_share`` of the ball's 99th percentile, none of whose channels is clipped (``clip``);
    painted markers are darker in that largest channel than the lit leather, and the median per
    channel ignores those that are not. Channels within 1.5 levels of the brightest count as
    equal to it (the resolution of a median of 8-bit values). Returns ``(1, 1, 1)`` when fewer than ``min_pixels``
    such pixels are found.
    """
    img = np.asarray(image)
    c = np.asarray(centers, float).reshape(-1, 2)
    r_all = np.broadcast_to(np.asarray(radii_px, float), (len(c),))
    H, W = img.shape[:2]
    picks = []
    for (cx, cy), r in zip(c, r_all):
        if not (np.isfinite(cx) and np.isfinite(cy) and np.isfinite(r) and r >= 3):
            continue
        x0, y0 = max(int(cx - r), 0), max(int(cy - r), 0)
        x1, y1 = min(int(cx + r) + 2, W), min(int(cy + r) + 2, H)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        crop = img[y0:y1, x0:x1]
        X = np.arange(x0, x1, dtype=np.float32)[None, :]
        Y = np.arange(y0, y1, dtype=np.float32)[:, None]
        inside = np.hypot(X - cx, Y - cy) <= inner_fraction * r
        if crop.dtype == np.uint8 and crop.ndim == 3:
            # the brightest channel of the 8-bit values, converted after (the same numbers:
            # float32 holds every code exactly), by two np.maximum on channel views (max(axis=2)
            # over 3 channels is a slow strided reduction); only the picked pixels converted
            v = np.maximum(np.maximum(crop[:, :, 0], crop[:, :, 1]), crop[:, :, 2]).astype(np.float32)
        else:
            crop = crop.astype(np.float32)
            v = crop.max(axis=2)
        if np.count_nonzero(inside) < 3:
            continue
        top = _percentile(v[inside], 99.0)
        sel = inside & (v >= lit_share * top) & (v < clip) & (v > 0)
        picks.append(crop[sel].astype(np.float32, copy=False))
    px = np.concatenate(picks) if picks else np.zeros((0, 3), np.float32)
    if len(px) < min_pixels:
        return np.ones(3)
    med = median_columns(px).astype(float)
    if not np.all(med > 0):
        return np.ones(3)
    # the median of 8-bit values resolves one level: channels within 1.5 levels of the
    # brightest are taken as equal to it (no cast measured)
    g = med / med.max()
    g[med.max() - med < 1.5] = 1.0
    return g


def detect_ball_markers(image, centers, radii_px, types: Sequence[MarkerType] | Mapping = BASEBALL_MARKER_TYPES,
                        min_area_px: float | None = None, hue_tol_deg: float = 30.0,
                        min_saturation: float = 0.2, min_value: float = 0.12, dark_ratio: float = 0.5,
                        weak_membership: float = 0.2,
                        lit_fraction: float = 0.2, disc_fraction: float = 0.97, limb_fraction: float = 0.8,
                        min_aspect: float = 0.4, reject_foreshortened: bool = False,
                        white_balance="auto", adapt_thresholds: bool = True, blur_px: float | None = None,
                        response=None, shading_model: bool = True, chroma_check: bool = True) -> BallMarkers:
    """Painted markers inside ball images (seed section 4.1: coloured regions inside each ball).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3)
        BGR photo (``uint8``, or float in 0-255), the one the balls were found in.
    centers : array_like, shape (N, 2)
        Ball image centres (raw pixels), e.g. ``BallDetections.centers``.
    radii_px : array_like, shape (N,) or scalar
        Ball image radii in pixels.
    types : sequence of MarkerType, or dict name -> (color_bgr, shape)
        The palette. Types whose colour has saturation >= 0.3 are told apart by hue; darker
        achromatic ones (value < 0.35) are dark regions; others (white, grey) cannot be told
        from the ball and raise ``ValueError``.
    min_area_px : float, optional
        Smallest marker region; default ``max(5, 0.003 * pi r^2)`` per ball.
    hue_tol_deg : float
        Largest hue difference (degrees, 0-360 scale) from a palette colour.
    min_saturation, min_value : float
        A pixel is clearly of a colour if its HSV saturation and value (0-1) reach these.
    dark_ratio : float
        A pixel is clearly dark (black marker) if its value is below this share of the local
        ball brightness (a morphological closing of the value that fills the markers in).
    weak_membership : float
        Regions grow from the clear pixels over pixels whose membership (saturation relative to
        the palette colour's, or darkness relative to the palette's) reaches this: blur and JPEG
        spread a small marker's colour over more pixels at lower saturation.
    lit_fraction : float
        Dark regions count only where the local ball brightness is at least this share of the
        ball's brightest: the unlit side of a half moon is not a marker.
    disc_fraction : float
        Markers are searched within this share of the radius (the outermost ring of pixels
        mixes ball and background).
    limb_fraction : float
        Markers whose centroid is further out than this share of the radius get ``NEAR_LIMB``.
    min_aspect : float
        Regions thinner than this minor/major ratio get ``FORESHORTENED`` (and are dropped with
        ``reject_foreshortened``).
    white_balance : "auto", None or array_like of 3 BGR gains
        The photo's colour cast, divided out before the colours are classified (the palette is
        the paint as a neutral camera photographs it): ``"auto"`` measures it on the balls' lit
        leather (:func:`ball_white_balance`), ``None`` takes the photo as neutral.
    adapt_thresholds : bool
        Scale ``min_saturation``, ``weak_membership`` and ``dark_ratio`` to the contrast the
        photo's markers reach (lens blur and small marker images lower it), never below the
        leather's noise; False keeps them as given.
    blur_px : float, optional
        The photo's lens blur (Gaussian sigma, px; e.g. measured on the balls' limbs,
        :func:`stillcap.ball.stereo.photo_blur_px`). Given, each centroid is corrected for the
        pull that blur and the ball's shading give it (:func:`shading_blur_shift`); None or 0:
        no correction.
    response : Response or its rig-file form, optional
        The camera's response (default sRGB): the shading model is fitted in linear light.
    shading_model : bool
        Measure each marker's darkness against the ball's shading fitted as a matte sphere
        (:func:`stillcap.detect._blur_shift._fit_shading`) where that model explains the leather
        (residual RMS within 10 % of its brightest), else against a morphological closing of the
        brightness; False: always the closing (as before issue 12).
    chroma_check : bool
        A dark region whose summed chroma a palette colour mostly explains is that colour's paint,
        or left out if mixed (JPEG, :func:`stillcap.detect._marker_chroma.recolor_dark`); and the
        lit pixels no region took are searched for coloured paint by their luma darkness alone,
        a region kept where its summed chroma names a colour (JPEG's 4:2:0 chroma leaves a small
        marker under the colour thresholds: :func:`~stillcap.detect._marker_chroma.luma_thresholds`).
        False: neither (dark regions are black).

    Returns
    -------
    BallMarkers
        Sorted by ball, then by x.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) (BGR), got {img.shape}")
    c = as_array(centers, (None, 2), "centers")
    r_in = np.asarray(radii_px, float)
    radii = np.broadcast_to(r_in, (len(c),)).astype(float) if r_in.ndim == 0 else as_array(r_in, (len(c),), "radii_px")
    tlist = _types(types)
    chroma, dark = [], []
    for t in tlist:
        kind, _ = marker_color_class(t.color_bgr)
        h, s, v = _hsv(t.color_bgr)
        if kind == "chromatic":
            # types of one colour (hues within 1 deg) are one colour class told apart by shape, as
            # the dark types are: (types, hue, saturation)
            same = next((c for c in chroma if abs((c[1] - h + 180.0) % 360.0 - 180.0) < 1.0), None)
            if same is None:
                chroma.append(([t], h, s))
            else:
                same[0].append(t)
        elif kind == "dark":
            dark.append(t)
        else:
            raise ValueError(f"marker type {t.name!r}: colour {t.color_bgr} is neither saturated nor dark; "
                             "it cannot be told from a white ball")
    H, W = img.shape[:2]
    if isinstance(white_balance, str):
        if white_balance != "auto":
            raise ValueError(f"white_balance must be 'auto', None or 3 BGR gains, got {white_balance!r}")
        wb = ball_white_balance(img, c, radii)
    elif white_balance is None:
        wb = np.ones(3)
    else:
        wb = as_array(white_balance, (3,), "white_balance")
        if not np.all(wb > 0):
            raise ValueError(f"white_balance gains must be positive, got {white_balance!r}")
    inv_wb = (1.0 / (255.0 * np.asarray(wb, float))).astype(np.float32)
    neutral = bool(np.all(np.abs(wb - 1.0) < 1e-12))
    # the palette in HSV, once per call: chromatic types stacked so each step below is one
    # array operation over all of them (float32 like the crop's hue, so the same arithmetic)
    ch_hue = np.array([h for _, h, _ in chroma], np.float32).reshape(-1, 1, 1)
    ch_sat = np.array([s for _, _, s in chroma], np.float32).reshape(-1, 1, 1)
    v_pal = min(_hsv(t.color_bgr)[2] for t in dark) if dark else 0.0
    rows = []
    # which balls' discs overlap (centres closer than the sum of the radii): computed once
    with np.errstate(invalid="ignore"):
        near = np.hypot(*(c[None, :, :] - c[:, None, :]).transpose(2, 0, 1)) < radii[None, :] + radii[:, None]
    near &= np.all(np.isfinite(c), axis=1)[None, :]
    np.fill_diagonal(near, False)
    prep, ch_peak, sat_lit, dk_lit, vc_lit, ch_noise, dl_lit = [], [], [], [], [], [], []
    shading = {}  # ball -> its shading model, for the blur correction (with blur_px)
    refl_shading = {}  # ball -> its light's drawn shading, for the markers near its terminator
    refl_rows = {}  # the centroids weighed in reflectance by id() (_measure; kept alive, so ids stay unique)
    sig_rows = {}  # id() of each centroid -> (centroid, its standard error in px) (_measure)
    lights = {}  # ball -> (light direction in its view frame, its error in deg), crop_light
    if blur_px is not None and not (np.isfinite(blur_px) and blur_px >= 0):
        raise ValueError(f"blur_px must be >= 0 px, got {blur_px}")
    resp = Response.srgb() if response is None else Response.from_json(response, "response")
    for bi in range(len(c)):
        cx, cy, r = c[bi, 0], c[bi, 1], radii[bi]
        if not (np.isfinite(cx) and np.isfinite(cy) and np.isfinite(r) and r >= 3):
            continue
        x0, y0 = max(int(np.floor(cx - r)) - 1, 0), max(int(np.floor(cy - r)) - 1, 0)
        x1, y1 = min(int(np.ceil(cx + r)) + 2, W), min(int(np.ceil(cy + r)) + 2, H)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        if neutral:
            crop = img[y0:y1, x0:x1].astype(np.float32)
            crop /= 255.0  # (in place: float32 / 255.0 is the same float32 division)
        else:  # the cast divided out (clipped at full scale: a clipped channel stays clipped)
            crop = img[y0:y1, x0:x1].astype(np.float32)
            np.minimum(np.multiply(crop, inv_wb, out=crop), 1.0, out=crop)  # in place: the same numbers
        hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
        hue, sat, val = hsv[..., 0], hsv[..., 1], hsv[..., 2]
        # pixel coordinates as a row (1, w) and a column (h, 1): they broadcast to the grid
        X = np.arange(x0, x1, dtype=np.float32)[None, :]
        Y = np.arange(y0, y1, dtype=np.float32)[:, None]
        dist = np.hypot(X - cx, Y - cy)
        disc = dist <= disc_fraction * r
        # pixels nearer (relative to radius) to another ball belong to that ball
        for bj in np.flatnonzero(near[bi]):
            disc &= dist / r <= np.hypot(X - c[bj, 0], Y - c[bj, 1]) / radii[bj]
        # Only the ball itself: the convex hull of its bright pixels inside the disc, one pixel in
        # (a radius a little too large, e.g. a silhouette's, would otherwise put the dark
        # background rim inside the disc, and dark rim = "black marker"). The hull fills the
        # notches that dark markers cut into the lit silhouette.
        fg = disc & (val >= min_value)
        if np.count_nonzero(fg) < 3:
            continue
        geo = disc.copy()  # the ball's disc by its geometry alone (terminator_weights reaches past the hull)
        disc &= cv2.erode(_hull_mask(fg), _BOX3).astype(bool)
        if not disc.any():
            continue
        min_area = max(5.0, 0.003 * np.pi * r * r) if min_area_px is None else float(min_area_px)
        # local ball brightness: closing fills markers up to ~0.35 r across
        k = max(3, int(round(0.35 * r)) | 1)
        ker = _ellipse_kernel(k)
        # (np.where of float32 and 0 is float32 already: the casts below copy nothing)
        vclose = cv2.morphologyEx(np.where(disc, val, 0).astype(np.float32, copy=False), cv2.MORPH_CLOSE, ker)
        top = _percentile(vclose[disc], 99.0)
        # luma darkness relative to the local white: every palette colour is much darker than
        # white paper in luma, and JPEG keeps luma at full resolution (chroma at half), so
        # centroids and shapes are measured on it; colour only says which region is which
        luma = cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY)
        lclose = cv2.morphologyEx(np.where(disc, luma, 0).astype(np.float32, copy=False), cv2.MORPH_CLOSE, ker)
        dark_luma = np.where(disc, np.clip(1.0 - luma / np.maximum(lclose, 1e-6), 0, 1), 0).astype(np.float32,
                                                                                                copy=False)
        lit = disc & (vclose >= max(lit_fraction * top, min_value))
        # The local white as a shaded sphere (fitted to the leather the closing finds) where that
        # model holds: a closing fills a marker from its brighter side on a shaded ball, which
        # pulls every centroid down the shading (0.1-0.3 px with 1.5 px of blur, "Blur" in
        # docs/spin.md); the model has no such pull.
        model = _fit_shading(luma, X, Y, cx, cy, r, lit & (dark_luma < 0.1), resp) if shading_model else None
        white = lclose
        fl = crop_light(luma, X, Y, cx, cy, r, light_disc(geo, dist, r), resp, model)  # the light (view frame)
        if fl is not None:
            lights[bi] = fl
        if model is not None:
            white = (resp.encode(_shading_at(model, X, Y)) / 255.0).astype(np.float32)
            dark_luma = np.where(disc, np.clip(1.0 - luma / np.maximum(white, 1e-6), 0, 1), 0).astype(np.float32,
                                                                                                    copy=False)
            if blur_px is not None and blur_px > 0:
                shading[bi] = model
        # markers reaching the terminator: their centroids against the light's clipped model
        # (_ball_light.terminator_weights)
        cen_w = near_t = None
        if fl is not None and model is not None:
            cen_w, near_t, drawn = terminator_weights(luma, X, Y, cx, cy, r, x0, y0, disc, dark_luma, fl, resp, blur_px,
                                                          geo)
            if blur_px is not None and blur_px > 0:  # the blur's pull (below) is then the drawn shading's
                refl_shading[bi] = drawn
        # the disc shrunk by one pixel (a marker reaching beyond it is AT_EDGE), once per ball
        inner = cv2.erode(disc.astype(np.uint8), _BOX3, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
        ratio = val / np.maximum(vclose, 1e-6)
        # the leather's luma relative to the white the centroids are weighed against, not clipped:
        # its spread around a marker is that marker's own noise (_measure, centroid_sigma_px)
        resid = 1.0 - luma / np.maximum(white, 1e-6)
        # what the photo's markers reach and the leather's noise (for the thresholds below)
        if chroma:
            dh = _hue_distance(hue, ch_hue)  # (types, h, w)
            hue_ok = (disc & (val >= min_value)) & (dh <= hue_tol_deg)
            ch_peak.append(np.where(hue_ok & lit, sat, 0.0).reshape(len(chroma), -1).max(axis=1))
        else:
            hue_ok = None
        if lit.any():
            sat_lit.append(sat[lit])
            dk_lit.append(1.0 - ratio[lit])
            vc_lit.append(vclose[lit])
            dl_lit.append(dark_luma[lit])
        # the chroma relative to the local white, for telling coloured paint from black (JPEG)
        ckm = (crop - luma[..., None], np.asarray(white, np.float32)) if (chroma and chroma_check) else None
        if ckm is not None:
            leather_px = lit & (dark_luma < 0.1)
            if leather_px.any():
                ch_noise.append((ckm[0][leather_px], ckm[1][leather_px]))
        prep.append((bi, cx, cy, r, X, Y, disc, val, sat, hue_ok, ratio, lit, inner, dark_luma, min_area, vclose,
                     ckm, cen_w, near_t, resid))
    # Thresholds relative to the photo (a stated model, not a tuning): the defaults are set
    # for markers whose cores reach the paint's full saturation (or darkness) ``ref``. Lens blur
    # and small marker images mix the paint with the leather, so the cores reach less (1.5 px
    # of blur leaves a 12 mm marker on a 15 px ball 15-40 % of it). Where the photo's markers
    # reach less (``peak``: the 90th percentile over the balls of each ball's strongest pixel of
    # that colour), both thresholds keep their share of what is reached, ``min(default, default
    # x peak / ref)``, never below the leather's own noise (median + 6 robust sigmas of its
    # lit pixels' saturation or darkness), so noise alone never makes a marker.
    # A colour's peak is evidence only above the noise (1.5x its ceiling): a colour no ball
    # shows (or only noise) takes the scale the others show, blur being one for all colours.
    # The saturation ceiling depends on the leather's brightness (``s_floor``, as the darkness
    # one does): HSV saturation divides by the value, so a sensor's noise makes dim leather (a
    # side light's terminator, a noisy sensor) far more saturated than bright leather. Pooled
    # over the ball, the dim pixels set the ceiling for all: measured on the robustness
    # benchmark's side-lit, blurred captures, 0.18-0.39 pooled against 0.11-0.15 on the brightest
    # leather, above the blurred markers' 0.2-0.4, so whole captures lost every coloured marker.
    # Each pixel's noise floor is the ceiling at its own local white (``vclose``; the bins made
    # non-increasing by an isotonic fit), and a colour's peaks are evidence where they stand
    # 1.5x above the ceiling at their own brightness.
    s_core, s_weak = np.full(len(chroma), min_saturation), np.full(len(chroma), weak_membership)
    d_core, d_weak = 1.0 - dark_ratio, weak_membership
    d_floor = None  # the leather's darkness noise as a function of its brightness (below)
    binned = None  # the lit pixels' brightness bins (_brightness_bins), for the three darkness measures
    s_floor, s_noise, ref, floors = None, None, ch_sat.reshape(-1).astype(float), None
    if adapt_thresholds and prep and sat_lit:
        sat_all, dk_all, vc_all = np.concatenate(sat_lit), np.concatenate(dk_lit), np.concatenate(vc_lit)
        s_noise = _robust_ceiling(sat_all)
        d_noise = _robust_ceiling(dk_all)
        binned = _brightness_bins(vc_all)
        d_floor = _noise_by_brightness(vc_all, dk_all, binned=binned)
        s_floor = _noise_by_brightness(vc_all, sat_all, monotone="isotonic", binned=binned)
        ref_d = max(1.0 - v_pal, 0.1)
        peaks = list(np.percentile(np.stack(ch_peak), 90, axis=0)) if chroma and ch_peak else []
        if chroma and ch_peak and s_floor is not None:
            floors = [np.interp(pp[15], *s_floor) for pp in prep]
            over = np.stack([np.where(pp[9] & pp[11], pp[8] / fl, 0.0).reshape(len(chroma), -1).max(axis=1)
                             for pp, fl in zip(prep, floors)])
            evidence = list(np.percentile(over, 90, axis=0) > 1.5)
        else:
            evidence = [pk > 1.5 * s_noise for pk in peaks]
        scales = [(pk / rf, ok) for pk, rf, ok in zip(peaks, ref, evidence)]
        # (the dark types take the chromatic ones' scale: the leather's shading and limb make
        # darkness without paint, never saturation, so darkness peaks are no evidence of blur)
        scales.append((1.0, False))
        seen = [min(sc, 1.0) for sc, ok in scales if ok]
        common = float(np.median(seen)) if seen else 1.0
        sc = np.array([min(v, 1.0) if ok else common for v, ok in scales])
        if chroma:  # the noise floor per pixel below (s_noise, or s_floor at the pixel's brightness)
            s_core = min_saturation * sc[:len(chroma)]
            s_weak = weak_membership * sc[:len(chroma)]
        if dark:
            d_core = max((1.0 - dark_ratio) * sc[-1], d_noise)
            d_weak = max(weak_membership * sc[-1], d_noise / ref_d)
    # coloured paint found by its luma darkness, named by its summed chroma (JPEG, _marker_chroma)
    luma_th = _mc.luma_thresholds([tl for tl, _, _ in chroma], dl_lit, vc_lit, dark_ratio, weak_membership,
                                  sc[-1] if adapt_thresholds and prep and sat_lit else 1.0,
                                  binned) if chroma_check else None
    s_core32 = s_core.astype(np.float32).reshape(-1, 1, 1)
    s_weak32 = s_weak.astype(np.float32).reshape(-1, 1, 1)
    ref32 = ref.astype(np.float32).reshape(-1, 1, 1)
    pal_u = np.array([_mc.chroma_per_darkness(tl[0].color_bgr) for tl, _, _ in chroma], float).reshape(-1, 3)
    k_leather, k_noise, w_lit = _mc.leather_chroma(ch_noise)
    for pi, (bi, cx, cy, r, X, Y, disc, val, sat, hue_ok, ratio, lit, inner, dark_luma, min_area, vclose,
             ck, cen_w, near_t, resid) in enumerate(prep):
        # Per type: a soft membership (1 = the palette colour, 0.5 ~ half covered pixel: a mix
        # of paint and white has about half the paint's saturation), regions of weak
        # membership that hold at least one clearly coloured pixel (hysteresis: a small or
        # foreshortened marker is blurred below the core threshold at its rim).
        cand = []  # (types, weak mask, core mask, soft)
        if chroma:
            soft = np.where(hue_ok, np.clip(sat / ch_sat, 0, 1), 0.0).astype(np.float32, copy=False)
            sw, sc_ = s_weak32, s_core32
            if s_noise is not None:  # never below the leather's noise at this brightness
                floor = np.float32(s_noise) if floors is None else floors[pi].astype(np.float32)
                sw, sc_ = np.maximum(sw, floor / ref32), np.maximum(sc_, floor)
            weak = soft >= sw
            core = hue_ok & (sat >= sc_)
            any_chroma = weak.any(axis=0)
            for i, (tl, _, _) in enumerate(chroma):
                cand.append((tl, weak[i], core[i], soft[i]))
        else:
            any_chroma = np.zeros_like(disc)
        if dark:
            lit_free = lit & ~any_chroma
            soft = np.where(lit_free, np.clip((1.0 - ratio) / max(1.0 - v_pal, 0.1), 0, 1), 0.0)
            soft = soft.astype(np.float32, copy=False)
            dc, dw = d_core, d_weak
            if d_floor is not None:  # dimmer leather is noisier: its own ceiling, never below the pooled one
                local = np.interp(vclose, *d_floor).astype(np.float32)
                dc, dw = np.maximum(d_core, local), np.maximum(d_weak, local / max(1.0 - v_pal, 0.1))
            cand.append((dark, soft >= dw, lit_free & (1.0 - ratio > dc), soft))
        if luma_th is not None and ck is not None and len(pal_u):
            soft = np.where(lit, np.clip(dark_luma / luma_th[0], 0, 1), 0.0).astype(np.float32, copy=False)
            local = 0.0 if luma_th[3] is None else np.interp(vclose, *luma_th[3]).astype(np.float32)
            cand.append((None, lit & (dark_luma >= np.maximum(luma_th[2], local)),
                         lit & (dark_luma >= np.maximum(luma_th[1], local)), soft))
        taken = np.zeros(disc.shape, np.uint8)  # the regions kept so far (the luma path takes the rest)
        for tl, weak, core, soft in cand:
            if tl is None:
                free = cv2.dilate(taken, _BOX3) == 0
                weak, core = weak & free, core & free
            if not core.any():
                continue
            n, lab, stats, _ = cv2.connectedComponentsWithStats(weak.view(np.uint8), connectivity=8)
            areas = stats[:, cv2.CC_STAT_AREA]
            has_core = np.bincount(lab[core], minlength=n) > 0
            for j in np.flatnonzero((areas[1:] >= min_area) & has_core[1:]) + 1:  # large enough, with a core
                rw = _measure(lab, j, soft, dark_luma, X, Y, stats[j], tl or chroma[0][0], float(areas[j]), bi,
                              cx, cy, r, disc, inner, limb_fraction, min_aspect, cen_w, near_t, refl_rows,
                              resid, sig_rows)
                if rw is not None and (tl is dark or tl is None) and ck is not None and len(pal_u):
                    named = _mc.recolor_dark(rw, lab, j, stats[j], dark_luma, ck, disc, pal_u, k_noise, chroma,
                                             k_leather, MarkerFlag.SHAPE_MISMATCH, w_lit, rows)
                    # a luma region is kept only where its chroma names a colour (black is the dark path's)
                    # and not a sliver (a thin luma region along a half moon's terminator is its shading)
                    rw = None if tl is None and (named is rw or rw[7] & MarkerFlag.FORESHORTENED) else named
                if rw is not None:
                    bx, by, bw, bh = stats[j, :4]
                    taken[by:by + bh, bx:bx + bw] |= (lab[by:by + bh, bx:bx + bw] == j).view(np.uint8)
                rows.append(rw)
    rows = [rw for rw in rows if rw is not None]
    err = [np.zeros(2)] * len(rows)
    if shading or refl_shading:
        for i, rw in enumerate(rows):
            model = (refl_shading if id(rw[0]) in refl_rows else shading).get(rw[6])
            if model is not None:
                shift, err[i] = shading_blur_correction(model, rw[0], float(blur_px))
                np.add(rw[0], shift, out=rw[0])
    keep = [i for i, rw in enumerate(rows) if not (reject_foreshortened and rw[7] & MarkerFlag.FORESHORTENED)]
    if not keep:
        return BallMarkers.empty()
    keep.sort(key=lambda i: (rows[i][6], rows[i][0][0], rows[i][0][1]))
    err, rows = np.array([err[i] for i in keep], float), [rows[i] for i in keep]
    return BallMarkers(
        centers=np.array([rw[0] for rw in rows], float), types=np.array([rw[1] for rw in rows], object),
        shapes=np.array([rw[2] for rw in rows], object), areas=np.array([rw[3] for rw in rows], float),
        confidences=np.array([rw[4] for rw in rows], float), aspects=np.array([rw[5] for rw in rows], float),
        ball_index=np.array([rw[6] for rw in rows], int), flags=np.array([int(rw[7]) for rw in rows], int),
        blur_error_px=err, light_view=np.array([lights[rw[6]][0] if rw[6] in lights else np.full(3, np.nan)
                                                for rw in rows], float).reshape(-1, 3),
        light_sigma_deg=np.array([lights[rw[6]][1] if rw[6] in lights else np.nan for rw in rows], float),
        centroid_sigma_px=np.array([sig_rows.get(id(rw[0]), (None, np.nan))[1] for rw in rows], float))
