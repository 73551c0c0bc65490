"""The camera sensor: linear radiance -> noisy, clipped, gamma-encoded 8-bit BGR (OpenCV order).

Model, per pixel and channel, with ``x = gain * radiance`` as a fraction of full scale: the
lens blurs the radiance with a Gaussian point-spread function (symmetric, so centres stay put);
shot noise of variance ``x / full_well`` (Poisson, Gaussian approximation) plus read noise of
standard deviation ``read_noise``; clip to [0, 1] (saturation); encode with the sRGB curve (or a
power law), optionally followed by a consumer camera's S-shaped tone curve; quantise to 8 bits;
optionally round-trip through JPEG with OpenCV so the artefacts are real ones. A white-balance
cast scales the radiance per channel before the noise.

:attr:`Sensor.response` gives the camera's true response (:class:`stillcap.response.Response`;
``.to_json()`` in the rig file's forms ``"srgb"``, ``"linear"``, ``{"gamma": g}``,
``{"lut": [256 linear values]}``): the studio writes it into the rig and the truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from scipy.special import ndtri

from stillcap._checks import as_rng
from stillcap.response import Response

_LEVELS = 16384  # linear quantisation before the 8-bit LUT: < 1 code value steps in the darks


@lru_cache(maxsize=1)
def _gauss_lut() -> np.ndarray:
    # 65536 equiprobable quantiles of N(0, 1): a uniform uint16 draw becomes a normal draw
    # (tails cut at 4.3 sigma). Several times faster than rng.standard_normal on full images.
    return ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)


#: Steepness of the consumer tone curve (:func:`tone_curve`): about 1.5x the contrast at mid-grey.
TONE_STRENGTH = 2.0


def tone_curve(y) -> np.ndarray:
    """A consumer camera's S-shaped tone curve on encoded values in [0, 1] (darker shadows,
    brighter highlights; 0, 0.5 and 1 stay put): ``0.5 + 0.5 tanh(k (y - 0.5)) / tanh(k / 2)``."""
    y = np.asarray(y, float)
    return 0.5 + 0.5 * np.tanh(TONE_STRENGTH * (y - 0.5)) / np.tanh(TONE_STRENGTH / 2)


def _encode(x, gamma, tone: bool) -> np.ndarray:
    """Linear [0, 1] -> encoded [0, 1] (before quantisation)."""
    x = np.asarray(x, float)
    if isinstance(gamma, Response):
        y = gamma.encode(np.clip(x, 0, 1)) / 255.0
    elif gamma == "srgb":
        y = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.clip(x, 0, None) ** (1 / 2.4) - 0.055)
    else:
        y = np.clip(x, 0, None) ** (1 / float(gamma))
    return tone_curve(y) if tone else y


@lru_cache(maxsize=8)
def _encode_lut(gamma, tone: bool = False) -> np.ndarray:
    x = np.arange(_LEVELS) / (_LEVELS - 1)
    return np.round(_encode(x, gamma, tone) * 255).astype(np.uint8)


def srgb_to_linear(image) -> np.ndarray:
    """Decode 8-bit sRGB values (any shape) to linear [0, 1] floats."""
    c = np.asarray(image, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@dataclass
class Sensor:
    """Exposure, noise and encoding of a camera.

    Parameters
    ----------
    gain : float
        Linear radiance -> fraction of full scale.
    full_well : float or None
        Electrons at full scale (shot noise); None disables shot noise.
    read_noise : float
        Read-noise standard deviation as a fraction of full scale.
    gamma : "srgb" or float
        Output encoding: the sRGB curve or ``x ** (1 / gamma)`` (1.0 = linear).
    jpeg_quality : int or None
        If set, the image is JPEG-encoded and decoded with OpenCV at this quality.
    blur_px : float
        Standard deviation of the lens's Gaussian point-spread function in pixels (0 = none).
    tone : bool
        Follow the encoding with a consumer camera's S-shaped tone curve (:func:`tone_curve`).
    white_balance : RGB
        Per-channel gains on the radiance (a colour cast; ``(1, 1, 1)`` = neutral).
    """

    gain: float = 1.0
    full_well: float | None = 10000.0
    read_noise: float = 0.002
    gamma: str | float = "srgb"
    jpeg_quality: int | None = None
    blur_px: float = 0.5
    tone: bool = False
    white_balance: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        wb = np.asarray(self.white_balance, float)
        if wb.shape != (3,) or not np.all(np.isfinite(wb)) or np.any(wb <= 0):
            raise ValueError(f"white_balance must be 3 positive RGB gains, got {self.white_balance!r}")
        self.white_balance = tuple(float(v) for v in wb)
        if not isinstance(self.gamma, Response) and self.gamma != "srgb" \
                and not (isinstance(self.gamma, (int, float)) and self.gamma > 0):
            raise ValueError(f"gamma must be 'srgb', a positive number or a Response, got {self.gamma!r}")
        if self.jpeg_quality is not None and not 0 <= int(self.jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality must be in 0..100, got {self.jpeg_quality}")
        if self.read_noise < 0 or (self.full_well is not None and self.full_well <= 0):
            raise ValueError("read_noise must be >= 0 and full_well > 0 (or None)")
        if not self.blur_px >= 0:
            raise ValueError(f"blur_px must be >= 0, got {self.blur_px}")

    @classmethod
    def ideal(cls, gain: float = 1.0, gamma: str | float = "srgb", blur_px: float = 0.0) -> Sensor:
        """A noise-free sensor behind a perfectly sharp lens (for truth-consistency tests)."""
        return cls(gain=gain, full_well=None, read_noise=0.0, gamma=gamma, blur_px=blur_px)

    @property
    def noisy(self) -> bool:
        return self.full_well is not None or self.read_noise > 0

    def expose(self, radiance, rng=None, detail_boxes=None) -> np.ndarray:
        """Turn linear RGB radiance ``(h, w, 3)`` into a uint8 BGR image ``(h, w, 3)``.

        ``detail_boxes``, pixel boxes ``(x0, y0, x1, y1)``, promise that the radiance outside
        them is smooth at the scale of the lens blur: the blur is then computed near them only
        (the renderer passes the boxes it drew bodies in).
        """
        rad = np.asarray(radiance)
        if rad.ndim != 3 or rad.shape[2] != 3:
            raise ValueError(f"radiance must have shape (h, w, 3), got {rad.shape}")
        rng = as_rng(rng)
        h, w, _ = rad.shape
        if self.blur_px > 0:
            rad = _blur(rad.astype(np.float32, copy=False), self.blur_px, detail_boxes)
        out = np.empty((h, w, 3), np.uint8)
        lut8, glut = _encode_lut(self.gamma, bool(self.tone)), _gauss_lut() if self.noisy else None
        wb = np.asarray(self.white_balance[::-1], np.float32) * np.float32(self.gain)  # BGR gains
        inv_fw = np.float32(0 if self.full_well is None else 1 / self.full_well)
        rn2 = np.float32(self.read_noise ** 2)
        step = max(1, 262144 // max(w, 1))  # row chunks keep the temporaries in cache
        for y0 in range(0, h, step):
            x = rad[y0:y0 + step, :, ::-1].astype(np.float32) * wb  # RGB -> BGR
            if glut is not None:
                z = glut[np.frombuffer(rng.bytes(2 * x.size), np.uint16).reshape(x.shape)]
                sd = np.maximum(x, 0) * inv_fw
                sd += rn2
                np.sqrt(sd, out=sd)
                z *= sd
                x += z
            np.clip(x, 0, 1, out=x)
            x *= _LEVELS - 1
            x += 0.5
            out[y0:y0 + step] = lut8[x.astype(np.uint16)]
        if self.jpeg_quality is not None:
            out = jpeg_roundtrip(out, int(self.jpeg_quality))
        return out

    def linearize(self, image) -> np.ndarray:
        """Approximate inverse of the encoding: uint8 BGR -> linear BGR fraction of full scale."""
        if self.tone:
            return np.asarray(self.response_lut(), float)[np.asarray(image, np.uint8)]
        if isinstance(self.gamma, Response):
            return self.gamma.linearize(np.asarray(image, float)).astype(float)
        if self.gamma == "srgb":
            return srgb_to_linear(image)
        return (np.asarray(image, float) / 255.0) ** float(self.gamma)

    def response_lut(self) -> list:
        """The inverse of the encoding as 256 linear values, one per 8-bit code (increasing)."""
        x = np.linspace(0.0, 1.0, 65537)
        y = _encode(x, self.gamma, bool(self.tone)) * 255
        # the code c is the encoded value's nearest integer: its linear value is where the curve crosses c
        return [float(v) for v in np.interp(np.arange(256), y, x)]

    @property
    def response(self) -> Response:
        """The camera's true response (what the studio writes into the rig it saves and into the
        truth; ``.to_json()`` gives the rig file's form): with the tone curve, its lookup table."""
        if self.tone:
            return Response.table(self.response_lut())
        if isinstance(self.gamma, Response):
            return self.gamma
        if self.gamma == "srgb":
            return Response.srgb()
        return Response.linear() if float(self.gamma) == 1.0 else Response.power(float(self.gamma))


def _blur(rad: np.ndarray, sigma: float, boxes) -> np.ndarray:
    """Gaussian blur of the whole image, or only within ``m = 4 sigma`` of ``boxes`` (the rest
    is smooth, so blurring leaves it unchanged)."""
    if boxes is None:
        return cv2.GaussianBlur(rad, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
    h, w = rad.shape[:2]
    m = int(np.ceil(4 * sigma)) + 1
    patches = []
    for x0, y0, x1, y1 in boxes:  # blur each box grown by 2m from the original, keep it grown by m
        X0, Y0, X1, Y1 = max(x0 - 2 * m, 0), max(y0 - 2 * m, 0), min(x1 + 2 * m, w), min(y1 + 2 * m, h)
        b = cv2.GaussianBlur(rad[Y0:Y1, X0:X1], (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        a0, b0, a1, b1 = max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, w), min(y1 + m, h)
        patches.append((slice(b0, b1), slice(a0, a1), b[b0 - Y0:b1 - Y0, a0 - X0:a1 - X0]))
    out = rad.copy()
    for ys, xs, p in patches:
        out[ys, xs] = p
    return out


def jpeg_roundtrip(image: np.ndarray, quality: int) -> np.ndarray:
    """Encode ``image`` as JPEG at ``quality`` with OpenCV and decode it again."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("OpenCV could not JPEG-encode the image")
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)


def consumer_tone_curve() -> Response:
    """A consumer camera's JPEG tone curve, as a lookup table: the sRGB curve followed by an
    S-shaped contrast boost (``0.7 t + 0.3 (1 - cos(pi t)) / 2`` of the sRGB value ``t``), the
    shape cameras' "standard" picture styles give. Effective gamma about 2.0."""
    t = np.arange(256) / 255.0
    # invert code -> sRGB value t numerically (the S-curve is monotonic), then decode sRGB
    grid = np.linspace(0, 1, 20001)
    s_curve = 0.7 * grid + 0.3 * (1 - np.cos(np.pi * grid)) / 2
    srgb_value = np.interp(t, s_curve, grid)
    return Response.table(np.clip(srgb_to_linear(srgb_value * 255.0), 0, 1))
