"""Shared pieces of the hand outputs: named views and formats, marker colours, the hand's degrees
of freedom with readable names, frame times, input checks, bone segments."""

from __future__ import annotations

import colorsys
import shutil
from collections.abc import Sequence
from typing import Callable

import numpy as np
from matplotlib.colors import to_rgb
from scipy.interpolate import interp1d

from stillcap._checks import as_array, as_positive
from stillcap.body.hand import DIGITS, HAND_COLORS, hand_dofs, hand_markerset
from stillcap.body.markerset import MarkerTrajectories
from stillcap.body.skeleton import Animation, Skeleton

#: Extensions :func:`write_hand_animation` writes.
ANIMATION_FORMATS = (".gif", ".mp4")
#: Named views of the animation: ``(elevation, azimuth)`` in degrees of matplotlib's 3D axes,
#: in the field frame (z up, y toward the pitcher, x to the catcher's right).
VIEWS = {
    "behind": (15.0, 90.0),  # from behind the pitcher (second base), like the hand rig's cameras
    "side": (10.0, 180.0),  # from the third-base side (a right-hander's arm side)
    "catcher": (10.0, -90.0),  # from home plate
    "top": (89.0, -90.0),  # from above, home plate at the bottom
}
_AXIS_NAMES = ("twist", "flexion", "abduction")  # intrinsic XYZ Euler axes of the hand's limits
_DIGIT_COLORS = {"thumb": "tab:purple", "index": "tab:blue", "middle": "tab:green", "ring": "tab:orange",
                  "little": "tab:brown"}

Progress = Callable[[int, int, str], None]


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------
def find_ffmpeg() -> str | None:
    """An ffmpeg program for MP4: imageio-ffmpeg's bundled binary if that package is installed,
    else ``ffmpeg`` on the ``PATH``; None when neither is there."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def _digit(name: str) -> str | None:
    head = name.split("-")[0]
    return head if head in DIGITS else None


def dof_labels(skeleton: Skeleton) -> list[tuple[int, int, str]]:
    """The hand's degrees of freedom with readable names.

    Returns
    -------
    list of (joint index, axis, label)
        In :func:`~stillcap.body.hand.hand_dofs` order; ``label`` like ``"index MCP flexion"``.
    """
    out = []
    for j, a in hand_dofs(skeleton):
        name = skeleton.names[j]
        d = _digit(name)
        joint = name.split("-", 1)[1].upper() if d and "-" in name else name
        out.append((j, a, f"{d + ' ' if d else ''}{joint} {_AXIS_NAMES[a]}"))
    return out


def _size(size, name: str = "size") -> tuple[int, int]:
    try:
        w, h = (int(s) for s in size)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be (width, height) in pixels, got {size!r}") from None
    if w < 64 or h < 64:
        raise ValueError(f"{name} must be at least 64 x 64 pixels, got {(w, h)}")
    return w, h


def _times(x, name: str) -> np.ndarray:
    t = as_array(x, (None,), name)
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} must be finite")
    return t


def animation_frame_times(times, fps: float = 25.0, slowdown: float = 40.0) -> np.ndarray:
    """The capture times (s) shown by the frames of a slow-motion video.

    A video at ``fps`` frames per second, ``slowdown`` times slower than real time, shows one
    frame every ``1 / (fps * slowdown)`` s of capture time, from the first to the last of
    ``times`` (a 1000 fps animation at 25 fps and 40x: one video frame per animation frame).
    """
    t = _times(times, "times")
    dt = 1.0 / (as_positive(fps, "fps") * as_positive(slowdown, "slowdown"))
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    return t[0] + dt * np.arange(n)


def _interp(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Values (first axis = time) linearly interpolated at ``at``; NaN outside ``times``."""
    if len(times) == 1:
        out = np.full((len(at),) + values.shape[1:], np.nan)
        out[np.isclose(at, times[0], rtol=0, atol=1e-9)] = values[0]
        return out
    return interp1d(times, values, axis=0, bounds_error=False, fill_value=np.nan, assume_sorted=True)(at)


def _marker_rgb(names: Sequence[str], colors) -> np.ndarray:
    """RGB in [0, 1] per marker: from ``colours`` (glove colour names, matplotlib names or RGB),
    else the hand marker set's colours when the names are its names, else grey."""
    n = len(names)
    if colors is None:
        ms = hand_markerset()
        if set(names) <= set(ms.names):
            return ms.rgb[[ms.index(nm) for nm in names]]
        return np.full((n, 3), 0.5)
    colors = list(colors)
    if len(colors) != n:
        raise ValueError(f"marker_colours must have one colour per marker ({n}), got {len(colors)}")
    out = []
    for c in colors:
        if isinstance(c, str) and c in HAND_COLORS:
            out.append(colorsys.hsv_to_rgb(*HAND_COLORS[c]))
        else:
            try:
                out.append(to_rgb(c))
            except ValueError:
                raise ValueError(f"marker_colours: {c!r} is not a colour name or RGB triple") from None
    return np.array(out, float)


def _marker_input(markers, animation: Animation) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """(times, points (n, M, 3), names) from MarkerTrajectories or an array on the animation's frames."""
    if isinstance(markers, MarkerTrajectories):
        return markers.times, markers.points, markers.names
    pts = np.asarray(markers, float)
    if pts.ndim != 3 or pts.shape[0] != animation.n_frames or pts.shape[2] != 3:
        raise ValueError(f"markers must be MarkerTrajectories or have shape ({animation.n_frames}, M, 3) "
                         f"(one row per animation frame), got {pts.shape}")
    return animation.times, pts, tuple(f"m{i}" for i in range(pts.shape[1]))


def _view(view) -> tuple[float, float]:
    if isinstance(view, str):
        if view not in VIEWS:
            raise ValueError(f"view must be one of {sorted(VIEWS)} or (elevation, azimuth) in degrees, got {view!r}")
        return VIEWS[view]
    try:
        elev, azim = (float(v) for v in view)
    except (TypeError, ValueError):
        raise ValueError(f"view must be one of {sorted(VIEWS)} or (elevation, azimuth) in degrees, "
                         f"got {view!r}") from None
    return elev, azim


def _bone_groups(skeleton: Skeleton) -> dict[str, list[tuple[int, int]]]:
    """(parent, child) bones per digit (``palm`` for bones leaving the root, ``body`` otherwise)."""
    groups: dict[str, list[tuple[int, int]]] = {}
    for c, p in enumerate(skeleton.parents):
        if p < 0:
            continue
        key = "palm" if p == skeleton.root else (_digit(skeleton.names[c]) or "body")
        groups.setdefault(key, []).append((int(p), c))
    return groups


def _segments(pos: np.ndarray, bones: list[tuple[int, int]]) -> tuple[np.ndarray, ...]:
    """x, y, z of line segments parent -> child, NaN-separated (one Line3D for many bones)."""
    seg = np.full((len(bones), 3, 3), np.nan)
    for i, (p, c) in enumerate(bones):
        seg[i, 0], seg[i, 1] = pos[p], pos[c]
    seg = seg.reshape(-1, 3)
    return seg[:, 0], seg[:, 1], seg[:, 2]


def _time_text(t: float, release_time_s: float | None) -> str:
    if release_time_s is None:
        return f"t = {t * 1e3:.1f} ms"
    return f"t = {(t - release_time_s) * 1e3:+.1f} ms from release"
