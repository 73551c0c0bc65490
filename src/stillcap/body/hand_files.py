"""The hand model and glove marker set from files (issue 12, part 3): ``stillcap hand
--hand-model FILE --markers FILE`` and ``capture.json``'s ``hand_model`` / ``hand_markers`` keys.

A hand model is a ``stillcap-skeleton`` file (``docs/skeleton.md``; the built-in one is
``data/hand_skeleton.json``, ``docs/hand.md``), a glove marker set a ``stillcap-markerset`` file
(``data/hand_markers.json``, ``docs/hand-markers.md``); both carry ``format`` and ``version`` and
are validated on reading (:mod:`stillcap.files.schema`). On top of the formats, a hand needs
(:func:`check_hand`): joints named after the digits (``thumb-cmc``, ``index-mcp``, ...; the
scale groups of :func:`~stillcap.body.hand.scale_groups`), the three back-of-hand markers
(:data:`~stillcap.body.hand.BACK_MARKERS`) on the root in three colours, and every marker in
one of the glove's colours (:data:`~stillcap.body.hand.HAND_COLORS`: the detector looks for
those only).

A reference is a built-in name (:data:`HAND_MODELS`, :data:`HAND_MARKERSETS`) or a path; a path
from a capture folder must stay inside it (:func:`stillcap.files.paths.resolve_inside`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stillcap.body.hand import BACK_MARKERS, HAND_COLORS, hand_markerset, hand_skeleton, scale_groups
from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton
from stillcap.files.paths import resolve_inside

__all__ = ["HAND_MODELS", "HAND_MARKERSETS", "read_hand_model", "read_hand_markers", "check_hand", "load_hand"]

#: Built-in hand models by name.
HAND_MODELS = {"hand-right-adult": hand_skeleton}
#: Built-in glove marker sets by name.
HAND_MARKERSETS = {"hand-18": hand_markerset}
#: Largest HSB distance (hue in turns, periodic) between a marker's colour and a glove colour.
COLOR_TOLERANCE = 0.1


def _path(ref, folder, what: str) -> Path:
    if folder is not None:
        return resolve_inside(folder, str(ref), what, "capture folder")
    return Path(ref)


def read_hand_model(ref, *, folder=None, what: str = "--hand-model") -> Skeleton:
    """A hand model by built-in name or from a ``stillcap-skeleton`` file (``folder``: the
    capture folder the path is relative to and must stay in)."""
    if isinstance(ref, str) and ref in HAND_MODELS:
        return HAND_MODELS[ref]()
    path = _path(ref, folder, what)
    return Skeleton.load(path) if folder is None else _named(Skeleton.load, path, what)


def read_hand_markers(ref, *, folder=None, what: str = "--markers") -> MarkerSet:
    """A glove marker set by built-in name or from a ``stillcap-markerset`` file."""
    if isinstance(ref, str) and ref in HAND_MARKERSETS:
        return HAND_MARKERSETS[ref]()
    path = _path(ref, folder, what)
    return MarkerSet.load(path) if folder is None else _named(MarkerSet.load, path, what)


def _named(load, path, what):
    try:
        return load(path)
    except ValueError as e:
        raise ValueError(f"{what}: {e}") from None


def check_hand(skeleton: Skeleton, markerset: MarkerSet, source: str = "hand") -> None:
    """ValueError in one line (naming ``source``) unless the skeleton and marker set make a hand
    the labelling can use (module docstring)."""
    try:
        scale_groups(skeleton)
        frames = markerset.bone_frames(skeleton)
    except ValueError as e:
        raise ValueError(f"{source}: {e}") from None
    names = list(markerset.names)
    missing = [n for n in BACK_MARKERS if n not in names]
    if missing:
        raise ValueError(f"{source}: the marker set has no back-of-hand marker(s) {missing} (needed: "
                         f"{list(BACK_MARKERS)} on the root joint)")
    back = [names.index(n) for n in BACK_MARKERS]
    if np.any(frames[back] != skeleton.root):
        raise ValueError(f"{source}: the back-of-hand markers {list(BACK_MARKERS)} must ride on the root joint "
                         f"{skeleton.names[skeleton.root]!r}")
    ref = np.array(list(HAND_COLORS.values()))
    for m in markerset.markers:
        d = np.abs(ref - np.array(m.hsb))
        d[:, 0] = np.minimum(d[:, 0], 1 - d[:, 0])
        if np.linalg.norm(d, axis=1).min() > COLOR_TOLERANCE:
            raise ValueError(f"{source}: marker {m.name!r} has colour hsb {list(m.hsb)}, none of the glove's colours "
                             f"({', '.join(f'{k} {list(v)}' for k, v in HAND_COLORS.items())})")
    from stillcap.body.hand import marker_colors

    if len({marker_colors(markerset)[i] for i in back}) != 3:
        raise ValueError(f"{source}: the back-of-hand markers must have three different colours")


def load_hand(model=None, markers=None, *, model_folder=None, markers_folder=None,
              model_what: str = "--hand-model", markers_what: str = "--markers") -> tuple[Skeleton, MarkerSet]:
    """``(skeleton, markerset)`` from references (None: the built-in ones), checked together."""
    sk = hand_skeleton() if model is None else read_hand_model(model, folder=model_folder, what=model_what)
    ms = hand_markerset() if markers is None else read_hand_markers(markers, folder=markers_folder, what=markers_what)
    parts = [f"{w} {r}" for w, r in ((model_what, model), (markers_what, markers)) if r is not None]
    check_hand(sk, ms, " with ".join(parts) or "the built-in hand")
    return sk, ms
