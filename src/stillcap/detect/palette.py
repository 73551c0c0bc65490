"""Marker colour palettes: reference colours, colour distances and maximally distinct palettes.

A :class:`Palette` is an ordered list of named reference colours (sRGB in [0, 1]). It converts
to the spaces the identification works in (HSB as in the thesis, CIE Lab) and measures how far
apart its colours are (:meth:`Palette.distances`).

:func:`propose_palette` answers the thesis's own "future work" item (SPEC J3: "colours chosen
to maximise their distances"): N saturated, bright colours, as far apart as possible in
CIEDE2000 (or Lab) and far from the black background, by farthest-point sampling over a dense
candidate set followed by swap improvement of the closest pair.

Colour spaces (all from scikit-image, D65 white):

- ``rgb``: sRGB in [0, 1] (gamma-encoded, what a JPEG stores);
- ``hsb``: hue in turns [0, 1), saturation and brightness in [0, 1] (HSV);
- ``lab``: CIE L*a*b*, L in [0, 100].
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
from pydantic import Field, RootModel
from skimage.color import hsv2rgb, rgb2hsv

from stillcap._checks import as_array, as_rng
from stillcap.files.jsonfile import read_json
from stillcap.files.schema import Fraction, Model, Name, validate

__all__ = [
    "METRICS",
    "Palette",
    "PaletteProposal",
    "ciede2000_pairwise",
    "color_distance",
    "hsb_distance",
    "propose_palette",
    "rgb_to_hsb",
    "rgb_to_lab",
]

#: Colour distances :func:`color_distance` knows.
METRICS = ("hsb", "lab", "ciede2000")


def rgb_to_lab(rgb, groups=None) -> np.ndarray:
    """sRGB in [0, 1], shape (N, 3) -> CIE Lab, shape (N, 3) (scikit-image, D65).

    ``skimage.color.rgb2lab``'s numbers bit for bit (its constants, its operations in the same
    order, its ``@`` with the same matrix layout), written out because on the identification's
    ~20 colours its input checks and dtype handling cost a third of the call (four calls per
    photo). ``test_rgb_to_lab_is_scikit_images_bit_for_bit`` checks it.

    ``groups``: row counts summing to N (e.g. the colours of several photos, one after the
    other): each group's rows converted as ``rgb_to_lab`` converts them alone. The element-wise
    steps run once over all rows; the matrix product, whose BLAS rounding may depend on how
    many rows it multiplies, once per group on that group's rows.
    """
    a = as_array(rgb, (None, 3), "rgb")
    if len(a) == 0:
        return np.zeros((0, 3))
    arr = np.clip(a, 0.0, 1.0)[None]
    # rgb2xyz: sRGB decoding (its masked updates as np.where: the same element-wise operations)
    arr = np.where(arr > 0.04045, np.power((arr + 0.055) / 1.055, 2.4), arr / 12.92)
    if groups is None:
        arr = arr @ _XYZ_FROM_RGB_T
    else:
        ends = np.cumsum(groups, dtype=int)
        if (int(ends[-1]) if len(ends) else 0) != len(a) or np.any(np.asarray(groups) < 0):
            raise ValueError(f"groups must be row counts summing to the {len(a)} colours, got {list(groups)}")
        arr = np.concatenate([arr[:, s:e] @ _XYZ_FROM_RGB_T for s, e in zip(ends - groups, ends) if e > s], axis=1)
    # xyz2lab, D65, 2-degree observer
    arr = arr / _XYZ_REF_WHITE
    arr = np.where(arr > 0.008856, np.cbrt(arr), 7.787 * arr + 16.0 / 116.0)
    x, y, z = arr[0, :, 0], arr[0, :, 1], arr[0, :, 2]
    return np.stack([(116.0 * y) - 16.0, 500.0 * (x - y), 200.0 * (y - z)], axis=-1)


def _skimage_lab_constants():
    from skimage.color import xyz_tristimulus_values
    from skimage.color.colorconv import xyz_from_rgb

    # the transposed matrix as rgb2xyz makes it (F order: a C-order copy multiplies with
    # different rounding)
    return xyz_from_rgb.T.astype(np.float64), xyz_tristimulus_values(illuminant="D65", observer="2",
                                                                      dtype=np.float64)


_XYZ_FROM_RGB_T, _XYZ_REF_WHITE = _skimage_lab_constants()


def rgb_to_hsb(rgb) -> np.ndarray:
    """sRGB in [0, 1], shape (N, 3) -> HSB (hue in turns, saturation, brightness), shape (N, 3)."""
    a = as_array(rgb, (None, 3), "rgb")
    if len(a) == 0:
        return np.zeros((0, 3))
    return rgb2hsv(np.clip(a, 0.0, 1.0)[None])[0]


def hsb_distance(a_hsb, b_hsb) -> np.ndarray:
    """The thesis's colour distance ``sqrt(dh^2 + ds^2 + db^2)`` with periodic hue.

    ``dh = min(|h1 - h2|, 1 - |h1 - h2|)`` (hue in turns: 0.999 is next to 0.001).

    Parameters
    ----------
    a_hsb : array_like, shape (N, 3)
    b_hsb : array_like, shape (K, 3)

    Returns
    -------
    ndarray, shape (N, K)
    """
    a = as_array(a_hsb, (None, 3), "a_hsb")
    b = as_array(b_hsb, (None, 3), "b_hsb")
    d = np.abs(a[:, None, :] - b[None, :, :])
    d[..., 0] = np.minimum(d[..., 0] % 1.0, 1.0 - d[..., 0] % 1.0)
    return np.sqrt((d**2).sum(axis=2))


def _lab_pairwise(a_lab, b_lab, metric: str, lightness_weight: float) -> np.ndarray:
    """(N, K) distances between Lab colours; ``lightness_weight`` scales the L term."""
    if metric == "lab":
        d = a_lab[:, None, :] - b_lab[None, :, :]
        d[..., 0] *= lightness_weight
        return np.sqrt((d**2).sum(axis=2))
    # CIEDE2000's kL divides the lightness term: weight w <=> kL = 1 / w.
    return ciede2000_pairwise(a_lab, b_lab, kL=1.0 / lightness_weight)


# np.deg2rad of these angles, bit for bit (x * pi / 180)
_RAD6, _RAD30, _RAD63 = math.radians(6), math.radians(30), math.radians(63)


def ciede2000_pairwise(a_lab, b_lab, kL: float = 1.0) -> np.ndarray:
    """CIEDE2000 between every colour of ``a_lab`` and every colour of ``b_lab``.

    The same numbers as ``skimage.color.deltaE_ciede2000(a[:, None], b[None], kL=kL)`` (the
    same formula, the same operations in the same order; kC = kH = 1), written out here because
    on the identification's small matrices (~20 x 16) scikit-image's input checks, axis moves and
    boolean-mask updates cost more than the arithmetic: 2-3x faster; the chroma of each colour
    is computed once instead of once per pair, and the masked updates are ``np.where``.

    Parameters
    ----------
    a_lab : array_like, shape (N, 3)
        CIE Lab colours (the first colour of each pair in CIEDE2000's asymmetric formula).
    b_lab : array_like, shape (K, 3)
    kL : float
        Lightness factor: the lightness difference is divided by it.

    Returns
    -------
    ndarray, shape (N, K)
    """
    a = as_array(a_lab, (None, 3), "a_lab")
    b = as_array(b_lab, (None, 3), "b_lab")
    two_pi = 2 * np.pi
    L1, a1, b1 = a.T[:, :, None]  # each (N, 1)
    L2, a2, b2 = b.T[:, None, :]  # each (1, K)
    Cbar = 0.5 * (np.hypot(a1, b1) + np.hypot(a2, b2))
    c7 = Cbar**7
    scale = 1 + 0.5 * (1 - np.sqrt(c7 / (c7 + 25**7)))
    x1, x2 = a1 * scale, a2 * scale
    C1, h1 = np.hypot(x1, b1), np.arctan2(b1, x1)
    C2, h2 = np.hypot(x2, b2), np.arctan2(b2, x2)
    h1 += np.where(h1 < 0.0, two_pi, 0)
    h2 += np.where(h2 < 0.0, two_pi, 0)
    Lbar = 0.5 * (L1 + L2)
    tmp = (Lbar - 50) ** 2
    SL = 1 + 0.015 * tmp / np.sqrt(20 + tmp)
    L_term = (L2 - L1) / (kL * SL)
    Cbar = 0.5 * (C1 + C2)
    SC = 1 + 0.045 * Cbar
    C_term = (C2 - C1) / (1 * SC)
    h_diff = h2 - h1
    h_sum = h1 + h2
    CC = C1 * C2
    zero = CC == 0.0
    dH = np.where(h_diff > np.pi, h_diff - two_pi, h_diff)
    dH = np.where(h_diff < -np.pi, dH + two_pi, dH)
    dH[zero] = 0.0
    dH_term = 2 * np.sqrt(CC) * np.sin(dH / 2)
    wrap = ~zero & (np.abs(h_diff) > np.pi)
    Hbar = np.where(wrap & (h_sum < two_pi), h_sum + two_pi, h_sum)
    Hbar = np.where(wrap & (h_sum >= two_pi), Hbar - two_pi, Hbar)
    Hbar = np.where(zero, Hbar * 2, Hbar)
    Hbar *= 0.5
    T = (1
         - 0.17 * np.cos(Hbar - _RAD30)
         + 0.24 * np.cos(2 * Hbar)
         + 0.32 * np.cos(3 * Hbar + _RAD6)
         - 0.20 * np.cos(4 * Hbar - _RAD63))
    SH = 1 + 0.015 * Cbar * T
    H_term = dH_term / (1 * SH)
    c7 = Cbar**7
    Rc = 2 * np.sqrt(c7 / (c7 + 25**7))
    dtheta = _RAD30 * np.exp(-(((np.rad2deg(Hbar) - 275) / 25) ** 2))
    R_term = -np.sin(2 * dtheta) * Rc * C_term * H_term
    dE2 = L_term**2
    dE2 += C_term**2
    dE2 += H_term**2
    dE2 += R_term
    return np.sqrt(np.maximum(dE2, 0))


def color_distance(a_rgb, b_rgb, metric: str = "ciede2000", lightness_weight: float = 1.0) -> np.ndarray:
    """Pairwise colour distances between two sets of sRGB colours.

    Parameters
    ----------
    a_rgb : array_like, shape (N, 3)
        sRGB in [0, 1].
    b_rgb : array_like, shape (K, 3)
    metric : {"hsb", "lab", "ciede2000"}
        ``hsb``: the thesis's HSB distance (:func:`hsb_distance`, units of [0, 1]);
        ``lab``: Euclidean CIE Lab distance (delta E 1976); ``ciede2000``: CIEDE2000.
    lightness_weight : float
        Weight of the lightness difference (``lab``: factor on dL; ``ciede2000``: 1 / kL).
        Below 1 it makes the distance tolerant of brighter or dimmer light. Ignored for ``hsb``.

    Returns
    -------
    ndarray, shape (N, K)
    """
    a = as_array(a_rgb, (None, 3), "a_rgb")
    b = as_array(b_rgb, (None, 3), "b_rgb")
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if not lightness_weight > 0:
        raise ValueError(f"lightness_weight must be > 0, got {lightness_weight}")
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    if metric == "hsb":
        return hsb_distance(rgb_to_hsb(a), rgb_to_hsb(b))
    return _lab_pairwise(rgb_to_lab(a), rgb_to_lab(b), metric, lightness_weight)


class PaletteColor(Model):
    """One entry of a palette file's ``colors`` (``hex`` and ``hsb`` may be present; ``rgb`` is read)."""

    name: Name
    rgb: tuple[Fraction, Fraction, Fraction]


class PaletteFile(Model):
    """A palette file (``stillcap palette --json``, ``stillcap puppet calibrate-palette``)."""

    colors: Annotated[list[PaletteColor], Field(min_length=1)]


_Byte = Annotated[float, Field(strict=True, ge=0, le=255, allow_inf_nan=False)]


class BGRPaletteFile(RootModel[Annotated[dict[Name, tuple[_Byte, _Byte, _Byte]], Field(min_length=1)]]):
    """A marker-ball palette (``stillcap markers --palette``): ``{label: [b, g, r]}``, 0-255."""


def read_bgr_palette(path) -> dict[str, tuple[float, float, float]]:
    """``{label: (b, g, r)}`` (0-255) from a marker-ball palette file; ValueError naming the file
    and the label on bad data."""
    where = f"palette file {path}"
    return {k: tuple(v) for k, v in validate(BGRPaletteFile, read_json(path, "palette file"), where).root.items()}


@dataclass(frozen=True, eq=False)
class Palette:
    """Named reference colours.

    Parameters
    ----------
    names : sequence of str, length K
    rgb : array_like, shape (K, 3)
        sRGB in [0, 1].
    """

    names: tuple[str, ...]
    rgb: np.ndarray

    def __post_init__(self):
        names = tuple(str(n) for n in self.names)
        if len(set(names)) != len(names):
            raise ValueError(f"palette names must be unique, got {list(names)}")
        rgb = as_array(self.rgb, (len(names), 3), "rgb")
        if not np.all(np.isfinite(rgb)) or rgb.min(initial=0) < 0 or rgb.max(initial=0) > 1:
            raise ValueError("rgb must be finite and lie in [0, 1]")
        rgb = rgb.copy()
        rgb.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "rgb", rgb)

    # -- constructors ------------------------------------------------------------------------
    @classmethod
    def from_hsb(cls, names, hsb) -> "Palette":
        """From HSB colours, shape (K, 3), hue in turns."""
        h = as_array(hsb, (len(names), 3), "hsb")
        return cls(names, hsv2rgb(np.clip(h, 0, 1)[None])[0] if len(h) else np.zeros((0, 3)))

    @classmethod
    def from_bgr8(cls, names, bgr) -> "Palette":
        """From OpenCV-order 8-bit colours, shape (K, 3), 0-255."""
        b = as_array(bgr, (len(names), 3), "bgr")
        return cls(names, np.clip(b[:, ::-1] / 255.0, 0, 1))

    @classmethod
    def from_dict(cls, data, source: str = "<palette>") -> "Palette":
        """From :meth:`to_dict` output (``{"colors": [{"name", "rgb"}, ...]}``); ValueError naming
        ``source`` and the key path on bad data."""
        f = validate(PaletteFile, data, source)
        names = [c.name for c in f.colors]
        for k, n in enumerate(names):
            if n in names[:k]:
                raise ValueError(f"{source}: colors.{k}.name: colour {n!r} is listed twice")
        return cls(names, np.array([c.rgb for c in f.colors], float))

    @classmethod
    def load(cls, path) -> "Palette":
        """Read a palette file (:meth:`from_dict`)."""
        return cls.from_dict(read_json(path, "palette file"), f"palette file {path}")

    @classmethod
    def from_markerset(cls, markerset) -> "Palette":
        """The reference colours of a :class:`~stillcap.body.markerset.MarkerSet` (e.g. ``MarkerSet.puppet()``)."""
        return cls(markerset.names, markerset.rgb)

    # -- views -------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown colour {name!r}; known: {', '.join(self.names)}") from None

    @property
    def hsb(self) -> np.ndarray:
        """HSB, shape (K, 3), hue in turns."""
        return rgb_to_hsb(self.rgb)

    @property
    def lab(self) -> np.ndarray:
        """CIE Lab, shape (K, 3)."""
        return rgb_to_lab(self.rgb)

    @property
    def bgr8(self) -> np.ndarray:
        """OpenCV-order 8-bit colours, shape (K, 3), uint8."""
        return np.round(self.rgb[:, ::-1] * 255).astype(np.uint8)

    @property
    def hex(self) -> tuple[str, ...]:
        """``#rrggbb`` strings."""
        return tuple("#" + "".join(f"{int(round(v * 255)):02x}" for v in c) for c in self.rgb)

    def distances(self, metric: str = "ciede2000", lightness_weight: float = 1.0) -> np.ndarray:
        """Pairwise distances between the palette's colours, shape (K, K) (see :func:`color_distance`)."""
        return color_distance(self.rgb, self.rgb, metric, lightness_weight)

    def min_distance(self, metric: str = "ciede2000", lightness_weight: float = 1.0) -> tuple[float, tuple[str, str]]:
        """The smallest pairwise distance and the pair of names that has it."""
        if len(self) < 2:
            return np.inf, ("", "")
        d = self.distances(metric, lightness_weight)
        d[np.diag_indices_from(d)] = np.inf
        i, j = np.unravel_index(np.argmin(d), d.shape)
        return float(d[i, j]), (self.names[i], self.names[j])

    def with_colors(self, rgb) -> "Palette":
        """The same names with new colours, shape (K, 3)."""
        return Palette(self.names, rgb)

    def apply_to(self, markerset):
        """A copy of ``markerset`` whose markers carry this palette's colours (matched by name).

        Markers whose name the palette lacks keep their colour.
        """
        markers = []
        for m in markerset.markers:
            if m.name in self.names:
                hsb = colorsys.rgb_to_hsv(*self.rgb[self.index(m.name)])
                m = replace(m, hsb=tuple(float(v) for v in np.clip(hsb, 0, 1)))
            markers.append(m)
        return replace(markerset, markers=tuple(markers))

    def to_dict(self) -> dict:
        """JSON-ready ``{"colors": [{"name", "hex", "rgb", "hsb"}, ...]}``."""
        return {
            "colors": [
                {"name": n, "hex": h, "rgb": [round(float(v), 4) for v in c], "hsb": [round(float(v), 4) for v in s]}
                for n, h, c, s in zip(self.names, self.hex, self.rgb, self.hsb)
            ]
        }


# -- palette design ----------------------------------------------------------------------------
@dataclass(eq=False)
class PaletteProposal:
    """Result of :func:`propose_palette`.

    Attributes
    ----------
    palette : Palette
    min_distance : float
        Smallest pairwise distance among the proposed colours (``metric``).
    closest_pair : tuple of str
    metric : str
    lightness_weight : float
    min_distance_to_excluded : float
        Smallest distance from a proposed colour to an excluded (background) colour.
    n_candidates : int
        Size of the candidate set searched.
    fixed : Palette or None
        The colours kept (``propose_palette(fixed=...)``); ``palette`` holds only the new ones.
    min_distance_to_fixed : float
        Smallest distance from a proposed colour to a kept one (inf without ``fixed``).
    closest_fixed : tuple of str
        (proposed, kept) names of that pair (empty strings without ``fixed``).
    """

    palette: Palette
    min_distance: float
    closest_pair: tuple[str, str]
    metric: str
    lightness_weight: float
    min_distance_to_excluded: float
    n_candidates: int
    fixed: Palette | None = None
    min_distance_to_fixed: float = math.inf
    closest_fixed: tuple[str, str] = ("", "")

    @property
    def guaranteed_distance(self) -> float:
        """What the proposal guarantees: no two proposed colours, and no proposed and kept
        colour, are closer than this (``min(min_distance, min_distance_to_fixed)``)."""
        return float(min(self.min_distance, self.min_distance_to_fixed))

    @property
    def combined(self) -> Palette:
        """The kept colours followed by the proposed ones (just the proposed without ``fixed``)."""
        if self.fixed is None:
            return self.palette
        return Palette(self.fixed.names + self.palette.names, np.vstack([self.fixed.rgb, self.palette.rgb]))


def _candidates(min_saturation, min_brightness, max_brightness, hue_steps, sv_steps) -> np.ndarray:
    """A dense grid of sRGB colours with HSB saturation and brightness in the limits, (M, 3)."""
    h = np.arange(hue_steps) / hue_steps
    s = np.linspace(min_saturation, 1.0, sv_steps)
    v = np.linspace(min_brightness, max_brightness, sv_steps)
    hsv = np.stack(np.meshgrid(h, s, v, indexing="ij"), axis=-1).reshape(-1, 3)
    return hsv2rgb(hsv[None])[0]


def propose_palette(n: int, rng=None, metric: str = "ciede2000", lightness_weight: float = 1.0,
                    min_saturation: float = 0.45, min_brightness: float = 0.6, max_brightness: float = 0.8,
                    min_lightness: float = 40.0,
                    exclude=((0.0, 0.0, 0.0), (0.15, 0.15, 0.15)), names=None,
                    restarts: int = 8, hue_steps: int = 120, sv_steps: int = 8, fixed=None,
                    min_grey: float = 0.0) -> PaletteProposal:
    """``n`` maximally distinct marker colours (or ``n`` more beside ``fixed`` ones).

    Maximises the smallest pairwise distance (a max-min or "dispersion" problem) over a dense
    grid of saturated, bright sRGB colours: farthest-point sampling from a random start, then
    swap improvement (replace one colour of the closest pair by the candidate that raises the
    minimum most, until no swap helps), best of ``restarts`` random starts. Written by hand:
    neither SciPy nor scikit-image offers max-min dispersion; it is a few vectorised lines
    over the candidate set.

    Parameters
    ----------
    n : int
        Number of colours (>= 1).
    rng : numpy.random.Generator or int, optional
    metric : {"ciede2000", "lab", "hsb"}
    lightness_weight : float
        Weight of lightness differences (see :func:`color_distance`). Below 1 favours colours
        that differ in hue and chroma, which survive brighter or dimmer light better.
    min_saturation, min_brightness, max_brightness : float
        HSB limits of the candidates, [0, 1]: saturated colours that stand out under the
        LEDs, with headroom below 1 so that brighter light does not clip a channel (a clipped
        channel shifts the hue). These are colours as the camera should see them at nominal
        exposure, like the thesis's reference colours (brightness 0.52-0.83).
    min_lightness : float
        Smallest CIE L* (0-100) of a candidate: deep blues and violets have full HSB brightness
        but look dark in a grey image, where the thesis's threshold must find them.
    exclude : array_like, shape (E, 3)
        sRGB colours the markers must stay away from (the black background, dark grey limbs).
        They take part in the farthest-point sampling as already chosen colours.
    names : sequence of str, optional
        Default ``c00, c01, ...``.
    restarts : int
    hue_steps, sv_steps : int
        Candidate grid resolution (hue x saturation x brightness).
    fixed : Palette or array_like, shape (F, 3), optional
        Colours that exist already (sRGB in [0, 1], e.g. ``Palette.from_markerset(MarkerSet.puppet())`` to add beads to
        the thesis's marker set): the ``n`` new colours maximise the smallest distance among
        themselves *and* to these (the distances among the kept colours cannot change and do
        not count). Names ``f00, f01, ...`` when an array is given.
    min_grey : float
        Smallest mean of a candidate's sRGB channels, [0, 1]: the puppet's bead detector looks
        for beads in the grey image (channel sum / 3), where a saturated red or blue is dim
        although its L* passes ``min_lightness``. On the benchmark's renders the thesis's beads
        with a grey level of 0.35-0.38 were found in 86-89 % of the views that show them, those
        of 0.47 and more in 99-100 %, and a new red bead (0.27) in 62 % (docs/puppet.md; measured
        with 16 candidates per photo for 20 beads, which costs the dimmest beads most).

    Returns
    -------
    PaletteProposal
        ``palette`` holds the ``n`` new colours; ``min_distance`` is the smallest distance
        among them, ``min_distance_to_fixed`` to the kept ones, ``guaranteed_distance`` the
        smaller of the two (the quantity maximised).
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n}")
    n = int(n)
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    if not (0 <= min_saturation <= 1 and 0 <= min_brightness <= max_brightness <= 1):
        raise ValueError("need 0 <= min_saturation <= 1 and 0 <= min_brightness <= max_brightness <= 1, got "
                         f"{min_saturation}, {min_brightness}, {max_brightness}")
    names = tuple(f"c{i:02d}" for i in range(n)) if names is None else tuple(names)
    if len(names) != n:
        raise ValueError(f"{len(names)} names for {n} colours")
    rng = as_rng(rng)
    exc = as_array(exclude, (None, 3), "exclude") if len(exclude) else np.zeros((0, 3))
    if fixed is not None and not isinstance(fixed, Palette):
        f = as_array(fixed, (None, 3), "fixed")
        fixed = Palette([f"f{i:02d}" for i in range(len(f))], f)
    if fixed is not None and set(fixed.names) & set(names):
        raise ValueError(f"names {sorted(set(fixed.names) & set(names))} are taken by the fixed colours")
    cand = _candidates(min_saturation, min_brightness, max_brightness, hue_steps, sv_steps)
    cand = cand[(rgb_to_lab(cand)[:, 0] >= min_lightness) & (cand.mean(axis=1) >= min_grey)]
    m = len(cand)
    if n > m:
        raise ValueError(f"n = {n} exceeds the {m} candidate colours")

    def dist(a_idx_or_rgb, b_rgb):
        return color_distance(a_idx_or_rgb, b_rgb, metric, lightness_weight)

    # Distances of every candidate to the excluded colours; candidates too close to them are
    # kept but start with that distance as their "nearest chosen" distance.
    d_exc = dist(cand, exc).min(axis=1) if len(exc) else np.full(m, np.inf)
    # Kept colours: every candidate's distance to the nearest of them is a hard part of the
    # objective (unlike the background's, which only steers the search); inf without them.
    d_fix = dist(cand, fixed.rgb).min(axis=1) if fixed is not None and len(fixed) else np.full(m, np.inf)
    d_exc = np.minimum(d_exc, d_fix)

    best_sel, best_val = None, -np.inf
    for _ in range(max(1, restarts)):
        sel = [int(rng.integers(m))]
        nearest = np.minimum(d_exc, dist(cand, cand[sel[0]][None])[:, 0])
        while len(sel) < n:
            k = int(np.argmax(nearest))
            sel.append(k)
            nearest = np.minimum(nearest, dist(cand, cand[k][None])[:, 0])
        # Swap improvement: D holds candidate-to-selected distances, (m, n).
        D = dist(cand, cand[sel])
        for _ in range(20 * n):
            S = D[sel].copy()
            S[np.diag_indices(n)] = np.inf
            cur = min(S.min(), d_fix[sel].min())
            i, j = np.unravel_index(np.argmin(S), S.shape)
            if d_fix[sel].min() < S.min():  # the closest pair is a new colour and a kept one
                i = j = int(np.argmin(d_fix[sel]))
            improved = False
            for drop in dict.fromkeys((i, j)):
                others = np.delete(np.arange(n), drop)
                inner = min(np.delete(np.delete(S, drop, 0), drop, 1).min(initial=np.inf),
                            d_fix[np.asarray(sel)[others]].min(initial=np.inf))
                gain = np.minimum(D[:, others].min(axis=1), d_exc)
                gain[sel] = -np.inf
                k = int(np.argmax(gain))
                if min(gain[k], inner) > cur + 1e-9:
                    sel[drop] = k
                    D[:, drop] = dist(cand, cand[k][None])[:, 0]
                    improved = True
                    break
            if not improved:
                break
        S = D[sel]
        S[np.diag_indices(n)] = np.inf
        val = min(S.min() if n > 1 else np.inf, d_fix[sel].min())
        if val > best_val:
            best_sel, best_val = list(sel), val
    # Order by hue for a readable palette.
    rgb = cand[best_sel]
    rgb = rgb[np.argsort(rgb_to_hsb(rgb)[:, 0], kind="stable")]
    pal = Palette(names, rgb)
    md, pair = pal.min_distance(metric, lightness_weight)
    dexc = float(dist(rgb, exc).min()) if len(exc) else np.inf
    dfix, fpair = math.inf, ("", "")
    if fixed is not None and len(fixed):
        F = dist(rgb, fixed.rgb)
        a, b = np.unravel_index(np.argmin(F), F.shape)
        dfix, fpair = float(F[a, b]), (names[a], fixed.names[b])
    return PaletteProposal(pal, md, pair, metric, float(lightness_weight), dexc, m, fixed, dfix, fpair)
