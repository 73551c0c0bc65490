"""Another person's hand for the hand studio (issue 12, part 6): a seedable generator of hands
unlike the model the pipeline ships, with their own motion, light and camera placement, so
that tests and benchmarks measure on hands the default model does not describe.

:func:`another_hand` draws (all uniform, seeded by ``rng``):

- **size**: every length times ``size`` (default within +-15 %);
- **proportions**: each phalanx and metacarpal length its own factor (default +-10 %);
- **finger splay**: the knuckles' spread across the palm (the MCP joints' radial position)
  its own factor per finger (+-``proportions`` x 1.5) and +-2 mm;
- **thumb axis**: the thumb's bones and markers turned together about a random axis through
  its CMC joint by up to ``thumb_axis_deg`` (default 12 deg), the CMC joint moved by +-4 mm;
- **marker heights**: each digit marker's height over the skin its own factor (+-20 %), and
  +-1.5 mm along and across its bone (a glove is not sewn to the millimetre); the back-of-hand
  markers +-1 mm;
- **motion**: every joint angle of the delivery offset by up to ``angle_deg`` (default 10 deg,
  within the joint limits);
- **light**: the strobe moved by up to 0.5 m sideways and 0.3 m up or down;
- **cameras**: each camera's azimuth +-8 deg, distance +-0.3 m, height +-0.25 m, focal length
  +-5 %.

The result is data (a :class:`HandVariation`); :func:`stillcap.studio.hand.hand_capture` takes
it as ``person=``. The skeleton and marker set are ordinary ones: the truth's joint angles are
measured on them, so the angle conventions are the model's (rest frames parallel to the hand
frame); what differs from the model is every length, the knuckles, the thumb and the markers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap._checks import as_rng
from stillcap.body.hand import DIGITS, hand_markerset, hand_skeleton
from stillcap.body.markerset import Marker, MarkerSet
from stillcap.body.skeleton import Joint, Skeleton

__all__ = ["HandVariation", "another_hand"]


@dataclass
class HandVariation:
    """Another person's hand, motion and studio (see the module docstring).

    Attributes
    ----------
    skeleton, markerset : Skeleton, MarkerSet
        The person's hand and glove markers.
    size : float
        Overall size relative to the model.
    angle_offsets_deg : ndarray, shape (n_joints, 3)
        Added to the delivery's joint angles.
    light_offset : ndarray, shape (3,)
        The strobe's displacement (m).
    layout : dict
        Camera name -> (azimuth deg, distance m, height m, focal px).
    """

    skeleton: Skeleton
    markerset: MarkerSet
    size: float
    angle_offsets_deg: np.ndarray
    light_offset: np.ndarray
    layout: dict


def another_hand(rng=None, *, size: float | None = None, size_spread: float = 0.15, proportions: float = 0.10,
                 thumb_axis_deg: float = 12.0, angle_deg: float = 10.0, studio: bool = True) -> HandVariation:
    """A seeded random hand unlike the model (module docstring).

    Parameters
    ----------
    rng : np.random.Generator or int, optional
    size : float, optional
        Fix the overall size (e.g. 1.15); default uniform in ``1 +- size_spread``.
    size_spread, proportions, thumb_axis_deg, angle_deg : float
        Ranges of the draws.
    studio : bool
        Also vary the light and the cameras (else the seed's).
    """
    from stillcap.studio.hand import _LAYOUT  # the seed's camera layout

    rng = as_rng(rng)
    if size is None:
        size = float(rng.uniform(1 - size_spread, 1 + size_spread))
    if not (np.isfinite(size) and 0.5 < size < 2.0):
        raise ValueError(f"size must be a factor between 0.5 and 2, got {size}")
    sk0, ms0 = hand_skeleton(), hand_markerset()
    names = sk0.names
    n = sk0.n_joints
    u = lambda lo, hi, shape=None: rng.uniform(lo, hi, shape)  # noqa: E731
    length = size * (1 + u(-proportions, proportions, n))
    offsets = sk0.offsets * length[:, None]
    # finger splay: the knuckles' radial position
    for d in DIGITS[1:]:
        i = sk0.index(f"{d}-mcp")
        offsets[i, 1] = sk0.offsets[i, 1] * size * (1 + u(-1.5 * proportions, 1.5 * proportions)) + u(-0.002, 0.002)
    # thumb axis: the thumb's bones and markers turned about its CMC joint
    thumb = [i for i in range(n) if names[i].startswith("thumb-")]
    cmc = sk0.index("thumb-cmc")
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(u(-thumb_axis_deg, thumb_axis_deg)))
    Rt = turn.as_matrix()
    offsets[cmc] += u(-0.004, 0.004, 3)
    for i in thumb:
        if i != cmc:
            offsets[i] = Rt @ offsets[i]
    joints = tuple(Joint(j.name, j.parent, o, j.limits_deg) for j, o in zip(sk0.joints, offsets))
    sk = Skeleton(joints, name=f"{sk0.name}-person", source="studio.hand_variation")

    frames = ms0.bone_frames(sk0)
    markers = []
    for m, f in zip(ms0.markers, frames):
        o = np.array(m.offset, float)
        if f == sk0.root:
            o = o * size + u(-0.001, 0.001, 3)
        else:
            b = sk0.index(m.bone)  # the bone the marker rides: its length scales the marker's place along it
            ratio = np.linalg.norm(offsets[b]) / np.linalg.norm(sk0.offsets[b])
            height = 1 + u(-0.2, 0.2)
            if names[b].startswith("thumb-"):
                # along the thumb's bone, and its height on the dorsal side, then turned with the thumb
                along = sk0.offsets[b] / np.linalg.norm(sk0.offsets[b])
                a = o @ along
                o = along * a * ratio + (o - along * a) * size * height + u(-0.0015, 0.0015, 3)
                o = Rt @ o
            else:
                o = np.array([o[0] * ratio + u(-0.0015, 0.0015), o[1] * size + u(-0.0015, 0.0015),
                              o[2] * size * height])
        markers.append(Marker(m.name, m.bone, o, m.hsb, m.diameter))
    ms = MarkerSet(tuple(markers), ms0.rules, ms0.name, sk.name, "studio.hand_variation")

    ang = u(-angle_deg, angle_deg, (n, 3))
    lim = sk0.limits_deg
    ang[np.isfinite(lim[..., 0]) & (lim[..., 1] <= lim[..., 0])] = 0.0  # locked axes stay locked
    if studio:
        light = np.array([u(-0.5, 0.5), u(-0.2, 0.2), u(-0.3, 0.3)])
        layout = {k: (az + u(-8, 8), dist + u(-0.3, 0.3), up + u(-0.25, 0.25), f * (1 + u(-0.05, 0.05)))
                  for k, (az, dist, up, f) in _LAYOUT.items()}
    else:
        light, layout = np.zeros(3), dict(_LAYOUT)
    return HandVariation(sk, ms, float(size), ang, light, layout)
