"""A ball painted at random, as a user might paint one (the robustness benchmark's "ball painted
at random" condition, issue 12 item 6: marker colours, sizes and positions; ball radius).

:func:`painted_ball` draws, from seeded randomness, what a user plausibly paints on a white ball:

- a radius of 34-42 mm and a mass for it (a baseball's density, +-15 %);
- 2-5 marker types: each a shape the ball format knows (disc, ring, square, triangle), a paint
  colour (a saturated hue, or a dark paint), a size of 4-8 mm from the marker's centre to its
  edge; two types may share a colour if their shapes differ, as the format allows;
- 6-16 markers, placed either by the project's layout designer (:func:`stillcap.ball.design.design_layout`,
  what ``stillcap balls design N`` gives a user) or "by hand": random directions kept a minimum
  angle apart, types assigned at random, with no care for how well they fix the ball frame.

The ball is returned as a :class:`~stillcap.ball.ballfile.Ball` that went through the ball
file's checks (:meth:`Ball.from_dict`), i.e. a file a user could have written.
"""

from __future__ import annotations

import colorsys
import math

import numpy as np

from stillcap._checks import as_rng
from stillcap.ball.ballfile import MIN_HUE_GAP_DEG, Ball, linear_to_srgb_hex
from stillcap.ball.design import design_layout
from stillcap.ball.layout import BallLayout
from stillcap.detect.ball_markers import SHAPES

__all__ = ["painted_ball", "hand_painted_directions"]

#: Radius range, m (issue 12: "ball radius" among what the studio varies).
RADIUS_RANGE_M = (0.034, 0.042)
#: A baseball's mass (kg) at a radius (m): the density a random ball's mass is scaled from
#: (then +-15 %).
_BASEBALL_MASS_KG, _BASEBALL_RADIUS_M = 0.145, 0.0366


def hand_painted_directions(n: int, min_sep_deg: float, rng=None, tries: int = 20000) -> np.ndarray:
    """``n`` unit vectors drawn uniformly on the sphere, each kept only if at least
    ``min_sep_deg`` from those kept before (random sequential addition), shape (n, 3).

    ``ValueError`` if ``n`` do not fit in ``tries`` draws."""
    rng = as_rng(rng)
    cos_max = math.cos(math.radians(min_sep_deg))
    out: list = []
    for _ in range(int(tries)):
        v = rng.standard_normal(3)
        v /= np.linalg.norm(v)
        if not out or np.max(np.asarray(out) @ v) < cos_max:
            out.append(v)
            if len(out) == n:
                return np.asarray(out)
    raise ValueError(f"could not place {n} markers {min_sep_deg:.1f} deg apart in {tries} draws")


def _paints(k: int, rng: np.random.Generator) -> list:
    """``k`` (colour as linear RGB, shape) pairs the ball format accepts: chromatic hues at least
    ``MIN_HUE_GAP_DEG`` (+ 5 deg) apart, at most one dark paint, a colour shared by two types only
    with different shapes."""
    hues: list = []
    out: list = []
    for _ in range(k):
        shapes_used = {}
        for c, s in out:
            shapes_used.setdefault(c, set()).add(s)
        reuse = [c for c in shapes_used if len(shapes_used[c]) < len(SHAPES)]
        if out and reuse and rng.random() < 0.2:  # a second shape in a colour already used
            color = reuse[int(rng.integers(len(reuse)))]
            shape = str(rng.choice([s for s in SHAPES if s not in shapes_used[color]]))
            out.append((color, shape))
            continue
        dark_used = any(max(c) < 0.05 for c, _ in out)
        if not dark_used and rng.random() < 0.25:
            v = float(rng.uniform(0.03, 0.2))  # sRGB value of a black or dark grey paint
            color = colorsys.hsv_to_rgb(float(rng.uniform(0, 1)), float(rng.uniform(0, 0.2)), v)
        else:
            for _ in range(1000):
                h = float(rng.uniform(0, 360))
                if all(abs((h - g + 180) % 360 - 180) >= MIN_HUE_GAP_DEG + 5 for g in hues):
                    break
            else:
                raise ValueError("no room for another hue")
            hues.append(h)
            color = colorsys.hsv_to_rgb(h / 360, float(rng.uniform(0.6, 1.0)), float(rng.uniform(0.45, 0.95)))
        srgb = np.asarray(color)
        lin = tuple(float(x) for x in np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4))
        out.append((lin, str(rng.choice(SHAPES))))
    return out


def painted_ball(rng=None, n_range=(6, 16), types_range=(2, 5), size_mm_range=(4.0, 8.0),
                 designed: bool | None = None) -> Ball:
    """A ball painted at random (module docstring).

    Parameters
    ----------
    rng : int or np.random.Generator
    n_range, types_range : (int, int)
        Marker count and type count, both inclusive.
    size_mm_range : (float, float)
        Marker size (centre to edge on the ball's surface), mm, drawn per type.
    designed : bool, optional
        Positions and types from the layout designer (True) or painted by hand (False); default
        either with probability 1/2.

    Returns
    -------
    Ball
        With ``description`` saying how it was painted.
    """
    rng = as_rng(rng)
    radius = float(rng.uniform(*RADIUS_RANGE_M))
    mass = _BASEBALL_MASS_KG * (radius / _BASEBALL_RADIUS_M) ** 3 * float(rng.uniform(0.85, 1.15))
    n = int(rng.integers(n_range[0], n_range[1] + 1))
    k = int(rng.integers(types_range[0], min(types_range[1], n) + 1))
    if designed is None:
        designed = bool(rng.random() < 0.5)
    paints = _paints(k, rng)
    names = [f"t{i}" for i in range(k)]
    sizes = [float(rng.uniform(*size_mm_range)) * 1e-3 / radius for _ in range(k)]
    kw = {"type_names": tuple(names), "type_shapes": tuple(s for _, s in paints),
          "palette": {nm: c for nm, (c, _) in zip(names, paints)}, "marker_size": max(sizes),
          "type_sizes": tuple(sizes), "radius": radius, "name": "painted"}
    if designed:
        template = BallLayout(np.eye(3)[:2], np.array([0, 0]), **kw)
        layout, _ = design_layout(n, k, template=template, rng=rng, restarts=2, sweeps=1, n_views=150,
                                  name="painted")
        how = f"designed ({n} markers, {k} types)"
    else:
        # a hand painter keeps the markers apart by about their own size or more
        min_sep = math.degrees(2 * max(sizes)) + float(rng.uniform(8.0, 20.0))
        d = hand_painted_directions(n, min_sep, rng)
        t = np.concatenate([np.arange(k), rng.integers(0, k, n - k)])
        layout = BallLayout(d, rng.permutation(t), **kw)
        how = f"painted by hand ({n} markers, {k} types, >= {min_sep:.0f} deg apart)"
    ball = Ball(layout, mass, "baseball", f"a ball painted at random: {how}")
    d = ball.to_dict()
    for t in d["types"]:
        t["color_srgb"] = linear_to_srgb_hex(t.pop("color_linear"))
    return Ball.from_dict(d, "painted ball")
