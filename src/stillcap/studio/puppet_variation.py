"""Another puppet: the studio's lay figure with other proportions and beads in other places, so
that tests and benchmarks measure on puppets unlike the default (issue 12, part 6).

:func:`another_puppet` draws, from a seed, a skeleton whose bones are each ``1 +- proportions``
times the built-in puppet's (left and right alike, up to a ``proportions / 15`` asymmetry; the pelvis raised or
lowered so the feet stay on the platform), and a marker set with the same bead names, colours and
rules whose beads are moved along their bones (``bead_shift_m``) and turned about them
(``bead_turn_deg``), at the same height above the bone axis times ``1 +- bead_height``.
Joint names, parents and limits stay the built-in puppet's (the pipeline's bead rules and the
studio's limbs refer to them).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_rng
from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.skeleton import Skeleton

__all__ = ["another_puppet"]

_LEG = ("hip", "knee", "foot")


def _side_key(name: str) -> str:
    return name[2:] if name[:2] in ("l-", "r-") else name


def another_puppet(rng=None, proportions: float = 0.15, bead_shift_m: float = 0.003, bead_turn_deg: float = 25.0,
                   bead_height: float = 0.15, markerset: MarkerSet | str | None = None
                   ) -> tuple[Skeleton, MarkerSet]:
    """A seedable puppet unlike the default.

    Parameters
    ----------
    rng : np.random.Generator or int, optional
    proportions : float
        Each bone's length is the built-in's times a factor drawn uniformly in
        ``[1 - proportions, 1 + proportions]`` (0.15: +-15 %).
    bead_shift_m : float
        Beads move along their bone by up to this much (uniform), metres; never past the bone's
        ends.
    bead_turn_deg : float
        Beads turn about their bone's axis by up to this much (uniform), degrees.
    bead_height : float
        A bead's distance from its bone's axis is the built-in's times ``1 + U(0, bead_height)``
        (never lower: it would sink into the limb).
    markerset : MarkerSet or str, optional
        The beads to move (default ``puppet-16``).

    Returns
    -------
    skeleton : Skeleton
    markerset : MarkerSet
    """
    if not 0 <= proportions < 0.5 or bead_shift_m < 0 or bead_height < 0:
        raise ValueError(f"proportions must be in [0, 0.5), bead_shift_m and bead_height >= 0, got "
                         f"{proportions}, {bead_shift_m}, {bead_height}")
    rng = as_rng(rng)
    base = Skeleton.puppet()
    ms = MarkerSet.resolve(markerset)
    ms.check_skeleton(base)
    factors: dict[str, float] = {}
    scale = np.ones(base.n_joints)
    for j, name in enumerate(base.names):
        key = _side_key(name)
        if key not in factors:
            factors[key] = float(rng.uniform(1 - proportions, 1 + proportions))
        asym = proportions / 15.0  # a small left/right asymmetry: +-1 % at +-15 % proportions
        scale[j] = factors[key] * float(rng.uniform(1 - asym, 1 + asym))
    off = base.offsets * scale[:, None]
    # the pelvis at the height that keeps the feet where the built-in puppet's are
    r = base.root
    legs = [base.index(f"{s}-{b}") for s in "lr" for b in _LEG]
    drop_base = -base.offsets[legs, 1].sum() / 2
    drop_new = -off[legs, 1].sum() / 2
    off[r] = base.offsets[r] + np.array([0.0, drop_new - drop_base, 0.0])
    skeleton = base.with_offsets(off, name=f"{base.name}-varied")
    markers = []
    for m in ms.markers:
        b = base.index(m.bone)
        axis = base.offsets[b] / base.bone_lengths[b]
        along = float(m.offset @ axis)
        perp = m.offset - along * axis
        s = skeleton.bone_lengths[b] / base.bone_lengths[b]
        new_along = float(np.clip(along * s + rng.uniform(-bead_shift_m, bead_shift_m), 0.0,
                                  skeleton.bone_lengths[b]))
        turn = Rotation.from_rotvec(axis * np.radians(rng.uniform(-bead_turn_deg, bead_turn_deg))).as_matrix()
        new_perp = turn @ perp * (1.0 + rng.uniform(0.0, bead_height))
        markers.append(Marker(m.name, m.bone, new_along * axis + new_perp, m.hsb, m.diameter))
    return skeleton, MarkerSet(tuple(markers), ms.rules, f"{ms.name}-varied", skeleton.name, "<another puppet>")
