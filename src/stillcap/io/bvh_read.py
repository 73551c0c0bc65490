"""Read BVH (Biovision hierarchy) motion files into an :class:`~stillcap.body.Animation`.

Conventions are those of Blender's and assimp's importers (and of :mod:`stillcap.io.export.bvh`):
rotation channels multiply in the listed order (``Zrotation Xrotation Yrotation`` ->
``R = Rz @ Rx @ Ry``), degrees; the root's position channels are its absolute position (the
root ``OFFSET`` is its rest position); BVH files do not state their length unit, so the
caller says it (``length_unit``, default centimetres). ``End Site`` blocks become leaf joints
named ``<parent>_end`` when ``end_sites=True``.

Hand-written: BVH is a small text format and no maintained reader is among the project's
dependencies.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stillcap.body.skeleton import LENGTH_UNITS, Animation, Joint, Skeleton

__all__ = ["read_bvh"]

_POS = ("Xposition", "Yposition", "Zposition")
_ROT = ("Xrotation", "Yrotation", "Zrotation")


def read_bvh(path: str | os.PathLike, length_unit: str = "cm", end_sites: bool = True) -> Animation:
    """Read a BVH file.

    Parameters
    ----------
    path : str or PathLike
    length_unit : {"cm", "m", "mm"}
        The unit of the file's offsets and positions (converted to metres).
    end_sites : bool
        Add each ``End Site`` as a leaf joint named ``<parent>_end``.

    Returns
    -------
    Animation
        Skeleton named after the file, times ``k * frame_time`` (seconds).

    Raises
    ------
    ValueError
        On malformed files (naming the file and what was expected), or a non-root joint
        whose position channels move it away from its offset.
    """
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise ValueError(f"length_unit must be one of {sorted(LENGTH_UNITS)}, got {length_unit!r}")
    scale = LENGTH_UNITS[length_unit]
    tokens = path.read_text(encoding="utf-8", errors="replace").split()
    pos = 0

    def fail(msg: str):
        raise ValueError(f"{path}: {msg} (at token {pos})")

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            fail("unexpected end of file")
        pos += 1
        return tokens[pos - 1]

    def expect(word: str) -> None:
        got = take()
        if got != word:
            fail(f"expected {word!r}, got {got!r}")

    names: list[str] = []
    parents: list[str | None] = []
    offsets: list[np.ndarray] = []
    channels: list[list[str]] = []

    def parse_joint(name: str, parent: str | None) -> None:
        expect("{")
        expect("OFFSET")
        try:
            off = np.array([float(take()) for _ in range(3)]) * scale
        except ValueError:
            fail(f"bad OFFSET of joint {name!r}")
        chans: list[str] = []
        if pos < len(tokens) and tokens[pos] == "CHANNELS":
            take()
            n = int(take())
            chans = [take() for _ in range(n)]
            bad = [c for c in chans if c not in _POS + _ROT]
            if bad:
                fail(f"unknown channel(s) {bad} of joint {name!r}")
        names.append(name)
        parents.append(parent)
        offsets.append(off)
        channels.append(chans)
        while True:
            word = take()
            if word == "}":
                return
            if word == "JOINT":
                parse_joint(take(), name)
            elif word == "End":
                expect("Site")
                expect("{")
                expect("OFFSET")
                site = np.array([float(take()) for _ in range(3)]) * scale
                expect("}")
                if end_sites:
                    names.append(f"{name}_end")
                    parents.append(name)
                    offsets.append(site)
                    channels.append([])
            else:
                fail(f"expected JOINT, End Site or '}}' in joint {name!r}, got {word!r}")

    expect("HIERARCHY")
    expect("ROOT")
    parse_joint(take(), None)
    expect("MOTION")
    expect("Frames:")
    n_frames = int(take())
    expect("Frame")
    expect("Time:")
    frame_time = float(take())
    n_ch = sum(len(c) for c in channels)
    try:
        values = np.array(tokens[pos:], dtype=float)
    except ValueError as e:
        raise ValueError(f"{path}: non-numeric motion data ({e})") from e
    if values.size != n_frames * n_ch:
        raise ValueError(f"{path}: expected {n_frames} frames x {n_ch} channels = {n_frames * n_ch} values, got {values.size}")
    if n_frames < 1 or not frame_time > 0:
        raise ValueError(f"{path}: needs at least one frame and a positive Frame Time")
    motion = values.reshape(n_frames, n_ch)

    n = len(names)
    skel = Skeleton(tuple(Joint(nm, pa, off) for nm, pa, off in zip(names, parents, offsets)), name=path.stem, source=str(path))
    local = np.tile(np.eye(3), (n_frames, n, 1, 1))
    root2world = np.tile(np.eye(4), (n_frames, 1, 1))
    root2world[:, :3, 3] = offsets[0]
    col = 0
    for j, chans in enumerate(channels):
        block = motion[:, col : col + len(chans)]
        col += len(chans)
        rot_idx = [k for k, c in enumerate(chans) if c in _ROT]
        pos_idx = [k for k, c in enumerate(chans) if c in _POS]
        if rot_idx:
            seq = "".join(chans[k][0] for k in rot_idx)
            if len(set(seq)) != len(seq):
                raise ValueError(f"{path}: joint {names[j]!r} repeats a rotation axis ({seq})")
            local[:, j] = Rotation.from_euler(seq, block[:, rot_idx], degrees=True).as_matrix()
        if pos_idx:
            p = np.zeros((n_frames, 3))
            p[:] = offsets[j]
            for k in pos_idx:
                p[:, "XYZ".index(chans[k][0])] = block[:, k] * scale
            if parents[j] is None:
                root2world[:, :3, 3] = p
            elif np.abs(p - offsets[j]).max() > 1e-9:
                raise ValueError(
                    f"{path}: joint {names[j]!r} has moving position channels; only the root may translate"
                )
    times = np.arange(n_frames) * frame_time
    return Animation(skel, times, root2world, local)
