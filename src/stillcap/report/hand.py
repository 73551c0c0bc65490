"""Outputs of a hand capture: a slow-motion animation of the hand and the ball (GIF or MP4),
joint-angle plots and an HTML report (issue 5, section 4; ``docs/hand-outputs.md``).

- :func:`write_hand_animation`: the hand skeleton (bones as lines, joints as dots, glove markers
  in their colours) and the ball (a sphere and its path) in 3D, field-frame axes in metres,
  slowed down so that a 60 ms release lasts seconds; the flashes (keyframes) are highlighted
  and leave a faint copy behind, like the strobe photo. ``.gif`` (Pillow, always available) or
  ``.mp4`` (needs an ffmpeg program: ``pip install imageio-ffmpeg`` or one on the ``PATH``).
- :func:`plot_joint_angles`: one panel per digit plus the hand's orientation, every degree of
  freedom of :func:`stillcap.body.hand.hand_dofs` over time in ms, keyframes as markers, the
  truth dashed; PNG.
- :func:`write_hand_report`: both of them and a ``report.html`` with the per-flash table (fit
  RMS, labelled markers), the joint angles per flash and the release summary, from plain
  dicts and arrays.

The inputs are plain: an :class:`~stillcap.body.Animation`, arrays of times (seconds) and
positions (metres, NaN = not seen), mappings of numbers. Every file is written atomically
(:mod:`stillcap.files.atomic`); matplotlib runs with the Agg backend (no display needed).
"""

from __future__ import annotations

import colorsys
import html
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import animation as mpl_animation  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from scipy.interpolate import interp1d  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from stillcap._checks import as_array, as_positive  # noqa: E402
from stillcap.ball.layout import BASEBALL_RADIUS as _BALL_RADIUS  # noqa: E402
from stillcap.body.hand import DIGITS, HAND_COLOURS, hand_dofs, hand_markerset  # noqa: E402
from stillcap.body.markerset import MarkerTrajectories  # noqa: E402
from stillcap.body.skeleton import Animation, Skeleton  # noqa: E402
from stillcap.files.atomic import atomic_path, write_text  # noqa: E402
from stillcap.report.pitch import _CSS, _fmt, _table, metric_unit  # noqa: E402

__all__ = ["ANIMATION_FORMATS", "VIEWS", "animation_frame_times", "dof_labels", "find_ffmpeg", "plot_joint_angles",
           "write_hand_animation", "write_hand_report"]

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
_DIGIT_COLOURS = {"thumb": "tab:purple", "index": "tab:blue", "middle": "tab:green", "ring": "tab:orange",
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


def _marker_rgb(names: Sequence[str], colours) -> np.ndarray:
    """RGB in [0, 1] per marker: from ``colours`` (glove colour names, matplotlib names or RGB),
    else the hand marker set's colours when the names are its names, else grey."""
    n = len(names)
    if colours is None:
        ms = hand_markerset()
        if set(names) <= set(ms.names):
            return ms.rgb[[ms.index(nm) for nm in names]]
        return np.full((n, 3), 0.5)
    colours = list(colours)
    if len(colours) != n:
        raise ValueError(f"marker_colours must have one colour per marker ({n}), got {len(colours)}")
    out = []
    for c in colours:
        if isinstance(c, str) and c in HAND_COLOURS:
            out.append(colorsys.hsv_to_rgb(*HAND_COLOURS[c]))
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


# --------------------------------------------------------------------------------------------
# animation
# --------------------------------------------------------------------------------------------
def write_hand_animation(path, animation: Animation, *, ball_times=None, ball_positions=None, keyframe_times=None,
                         markers=None, marker_colours=None, fps: float = 25.0, slowdown: float = 40.0,
                         view="behind", follow: bool = False, size=(640, 480), dpi: int = 100,
                         release_time_s: float | None = None, title: str = "hand", ball_radius: float = _BALL_RADIUS,
                         progress: Progress | None = None) -> Path:
    """Write a slow-motion 3D animation of the hand (and ball) as GIF or MP4.

    Parameters
    ----------
    path : str or PathLike
        ``.gif`` (Pillow) or ``.mp4`` (H.264 through an ffmpeg program, :func:`find_ffmpeg`).
    animation : Animation
        The hand's motion (field frame, metres), e.g. 1000 fps over the capture window.
    ball_times : array_like, shape (B,), optional
        Seconds, strictly increasing; with ``ball_positions``.
    ball_positions : array_like, shape (B, 3), optional
        Ball centre (m); NaN where unknown. Drawn as a sphere of ``ball_radius`` and its path.
    keyframe_times : array_like, shape (K,), optional
        Flash times (s). The video frame nearest each one is highlighted, and the hand and ball
        of each flash stay behind as a faint copy (like the multi-exposure photo).
    markers : MarkerTrajectories or array_like, shape (n_frames, M, 3), optional
        Glove markers (m, NaN = unseen); an array has one row per animation frame.
    marker_colours : sequence, optional
        One colour per marker: a glove colour name (:data:`~stillcap.body.hand.HAND_COLOURS`),
        a matplotlib colour name or an RGB triple. Default: the glove's colours when the markers
        are named like the hand marker set, else grey.
    fps : float
        Video frames per second.
    slowdown : float
        Times slower than real time: one video frame every ``1 / (fps * slowdown)`` s of capture
        (:func:`animation_frame_times`). Default 40: a 1000 fps animation at 25 fps shows every
        frame, and 60 ms last 2.4 s.
    view : str or (float, float)
        A name of :data:`VIEWS` or ``(elevation, azimuth)`` in degrees.
    follow : bool
        False: fixed limits around everything over the whole take. True: a cube of fixed size
        (the hand's largest extent plus a margin) centred on the hand in each frame, to see
        the fingers.
    size : (int, int)
        Width and height in pixels (even numbers for MP4).
    dpi : int
        Figure resolution (sets the text size relative to ``size``).
    release_time_s : float, optional
        Times in the title are then in ms from release.
    title : str
        Title prefix.
    ball_radius : float
        Metres.
    progress : callable, optional
        ``progress(done, total, label)`` after each video frame.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        For an extension other than ``.gif`` / ``.mp4`` or inputs of the wrong shape.
    ImportError
        For ``.mp4`` when no ffmpeg program is found (names what to install).
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in ANIMATION_FORMATS:
        raise ValueError(f"cannot write {path.name!r}: the animation is written as {' or '.join(ANIMATION_FORMATS)}, "
                         f"got extension {ext or '(none)'!r}")
    if not isinstance(animation, Animation):
        raise ValueError(f"animation must be an Animation, got {type(animation).__name__}")
    w, h = _size(size)
    dpi = int(as_positive(dpi, "dpi"))
    fps = as_positive(fps, "fps")
    elev, azim = _view(view)
    ball_radius = as_positive(ball_radius, "ball_radius")
    if (ball_times is None) != (ball_positions is None):
        raise ValueError("ball_times and ball_positions go together: give both or neither")
    t_vid = animation_frame_times(animation.times, fps, slowdown)
    n_vid = len(t_vid)
    joints = _interp(animation.times, animation.positions, t_vid)
    if ball_times is not None:
        bt = _times(ball_times, "ball_times")
        if len(bt) > 1 and np.any(np.diff(bt) <= 0):
            raise ValueError("ball_times must be strictly increasing")
        bp = as_array(ball_positions, (len(bt), 3), "ball_positions")
        ball = _interp(bt, bp, t_vid)
    else:
        bt, bp, ball = None, None, None
    if markers is not None:
        mt, mp, mnames = _marker_input(markers, animation)
        mrgb = _marker_rgb(mnames, marker_colours)
        mvid = _interp(mt, mp, t_vid)
    else:
        mvid = mrgb = None
    keys = np.empty(0) if keyframe_times is None else _times(keyframe_times, "keyframe_times")
    # the video frame nearest each keyframe (within half a video frame): highlighted
    dt = t_vid[1] - t_vid[0] if n_vid > 1 else 1.0
    key_frame = {}
    for i, tk in enumerate(keys):
        k = int(np.argmin(np.abs(t_vid - tk)))
        if abs(t_vid[k] - tk) <= 0.5 * dt + 1e-12:
            key_frame[k] = i
    ghosts_pos = _interp(animation.times, animation.positions, keys) if len(keys) else np.empty((0,) + joints.shape[1:])
    ghosts_ball = _interp(bt, bp, keys) if (bt is not None and len(keys)) else None
    if ext == ".mp4":
        if w % 2 or h % 2:
            raise ValueError(f"size must be even for MP4 (H.264 with yuv420p), got {(w, h)}")
        ffmpeg = find_ffmpeg()
        if ffmpeg is None:
            raise ImportError("writing MP4 needs an ffmpeg program: pip install imageio-ffmpeg "
                              "(or install ffmpeg on the PATH, e.g. apt-get install ffmpeg); GIF needs nothing")
        writer = mpl_animation.FFMpegWriter(fps=fps, codec="h264", bitrate=-1)
        rc = {"animation.ffmpeg_path": ffmpeg}
    else:
        writer = mpl_animation.PillowWriter(fps=fps)
        rc = {}

    # limits: a cube (equal aspect) fixed over the take, or of fixed size following the hand
    hand_pts = joints.reshape(-1, 3)
    every = [hand_pts]
    if ball is not None:
        every.append(bp)
    if mvid is not None:
        every.append(mvid.reshape(-1, 3))
    allp = np.concatenate(every)
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    if not len(allp):
        raise ValueError("nothing to draw: every joint position is NaN")
    if follow:
        with np.errstate(invalid="ignore"):
            ext_hand = np.nanmax(np.nanmax(joints, axis=1) - np.nanmin(joints, axis=1))
        half = 0.5 * max(float(ext_hand), 0.05) * 1.5 + ball_radius
    else:
        half = 0.5 * max(float(np.ptp(allp, axis=0).max()), 0.05) * 1.08 + ball_radius
    fixed_centre = 0.5 * (allp.min(axis=0) + allp.max(axis=0))

    fig = plt.figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 0.9), projection="3d")
    ax.view_init(elev=elev, azim=azim)
    ax.set_box_aspect((1, 1, 1), zoom=1.1)  # equal aspect; zoom fills the figure
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    ax.set_zlabel("z (m)", fontsize=7)
    ax.tick_params(labelsize=6)
    heading = fig.text(0.5, 0.955, "", ha="center", va="center", fontsize=10)
    fig.text(0.5, 0.91, "field frame, metres" + (f"; {slowdown:g}x slower" if slowdown != 1 else ""),
                   ha="center", va="center", fontsize=7, color="0.4")

    skel = animation.skeleton
    groups = _bone_groups(skel)
    clip = {"axlim_clip": True} if follow else {}  # the moving cube hides what leaves it
    bone_lines = {g: ax.plot([], [], [], "-", lw=2.0, color=_DIGIT_COLOURS.get(g, "0.25"), solid_capstyle="round",
                             **clip)[0] for g in groups}
    joint_dots = ax.plot([], [], [], "o", ms=2.5, color="0.1", ls="none", **clip)[0]
    marker_lines = []
    if mvid is not None:
        for rgb in np.unique(mrgb, axis=0):
            idx = np.flatnonzero(np.all(mrgb == rgb, axis=1))
            line = ax.plot([], [], [], "o", ms=5, ls="none", color=rgb, mec="k", mew=0.4, **clip)[0]
            marker_lines.append((idx, line))
    ball_done = None
    if ball is not None:
        ok = np.all(np.isfinite(bp), axis=1)
        ax.plot(bp[ok, 0], bp[ok, 1], bp[ok, 2], ":", lw=0.8, color="0.55", **clip)  # the whole path, faint
        ball_done = ax.plot([], [], [], "-", lw=1.2, color="0.3", **clip)[0]
    ghost_lines = []  # added as flashes pass
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 13), np.linspace(0, np.pi, 7))
    unit_sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)])
    sphere = [None]

    def set_limits(centre):
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)

    set_limits(fixed_centre)

    def draw(k: int):
        pos = joints[k]
        for g, bones in groups.items():
            bone_lines[g].set_data_3d(*_segments(pos, bones))
            bone_lines[g].set_linewidth(3.2 if k in key_frame else 2.0)
        joint_dots.set_data_3d(pos[:, 0], pos[:, 1], pos[:, 2])
        for idx, line in marker_lines:
            m = mvid[k, idx]
            line.set_data_3d(m[:, 0], m[:, 1], m[:, 2])
        if sphere[0] is not None:
            sphere[0].remove()
            sphere[0] = None
        if ball is not None:
            past = bt <= t_vid[k] + 1e-12
            trail = np.concatenate([bp[past], ball[k : k + 1]])
            ball_done.set_data_3d(trail[:, 0], trail[:, 1], trail[:, 2])
            if np.all(np.isfinite(ball[k])):
                s = ball[k][:, None, None] + ball_radius * unit_sphere
                sphere[0] = ax.plot_surface(s[0], s[1], s[2], color="0.93", edgecolor="0.55", lw=0.2, shade=True,
                                            **clip)
        if k in key_frame:  # this flash's hand (and ball) stays behind, faint
            i = key_frame[k]
            for bones in groups.values():
                ghost_lines.append(ax.plot(*_segments(ghosts_pos[i], bones), "-", lw=1.0, color="0.6", alpha=0.6,
                                           **clip))
            if ghosts_ball is not None and np.all(np.isfinite(ghosts_ball[i])):
                gb = ghosts_ball[i]
                ghost_lines.append(ax.plot([gb[0]], [gb[1]], [gb[2]], "o", ms=6, mfc="none", color="0.5", **clip))
        if follow:
            c = np.nanmean(pos, axis=0)
            set_limits(c if np.all(np.isfinite(c)) else fixed_centre)
        text = f"{title}: {_time_text(t_vid[k], release_time_s)}"
        if k in key_frame:
            heading.set_text(f"{text}   FLASH {key_frame[k] + 1}")
            heading.set_color("tab:red")
            heading.set_fontweight("bold")
        else:
            heading.set_text(text)
            heading.set_color("k")
            heading.set_fontweight("normal")

    try:
        with matplotlib.rc_context(rc), atomic_path(path) as tmp:
            with writer.saving(fig, str(tmp), dpi):
                for k in range(n_vid):
                    draw(k)
                    writer.grab_frame()
                    if progress is not None:
                        progress(k + 1, n_vid, f"animation frame {k + 1}/{n_vid}")
    finally:
        plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------
# joint angles
# --------------------------------------------------------------------------------------------
def _orientation_deg(root2world: np.ndarray) -> np.ndarray:
    """The hand's orientation in the field frame as intrinsic ZYX angles (yaw about z, pitch,
    roll), degrees, unwrapped over time; shape (n, 3)."""
    ang = Rotation.from_matrix(root2world[:, :3, :3]).as_euler("ZYX")
    return np.degrees(np.unwrap(ang, axis=0))


def plot_joint_angles(path, times, angles_deg, skeleton: Skeleton, *, keyframe_times=None, truth_times=None,
                      truth_angles_deg=None, root2world=None, truth_root2world=None,
                      release_time_s: float | None = None, size=(1200, 800), dpi: int = 100,
                      title: str = "Hand joint angles") -> Path:
    """Plot the hand's joint angles over time: one panel per digit and one for the hand's
    orientation; PNG.

    Parameters
    ----------
    path : str or PathLike
        A ``.png`` file.
    times : array_like, shape (n,)
        Seconds, increasing.
    angles_deg : array_like, shape (n, n_joints, 3)
        Twist, flexion, abduction (intrinsic XYZ Euler, as
        :meth:`~stillcap.body.Skeleton.limit_angles_deg` reads them), degrees; NaN = unknown.
        Each digit's panel shows its degrees of freedom (:func:`dof_labels`).
    skeleton : Skeleton
        The hand (:func:`~stillcap.body.hand.hand_skeleton` or a scaled one).
    keyframe_times : array_like, shape (K,), optional
        Flash times (s): markers on the curves and faint vertical lines.
    truth_times : array_like, shape (m,), optional
    truth_angles_deg : array_like, shape (m, n_joints, 3), optional
        Drawn dashed in the same colours.
    root2world : array_like, shape (n, 4, 4), optional
        The hand's pose; its orientation (ZYX yaw, pitch, roll in the field frame, unwrapped) fills
        the first panel. ``truth_root2world`` (m, 4, 4) likewise, dashed.
    release_time_s : float, optional
        Times are then in ms from release (a vertical line marks it).
    size : (int, int)
        Width and height in pixels.
    dpi : int
    title : str

    Returns
    -------
    Path
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot_joint_angles writes PNG, got {path.name!r}")
    w, h = _size(size)
    dpi = int(as_positive(dpi, "dpi"))
    nj = skeleton.n_joints
    t = _times(times, "times")
    ang = as_array(angles_deg, (len(t), nj, 3), "angles_deg")
    r2w = None if root2world is None else as_array(root2world, (len(t), 4, 4), "root2world")
    keys = np.empty(0) if keyframe_times is None else _times(keyframe_times, "keyframe_times")
    tt = tang = tr2w = None
    if (truth_times is not None) != (truth_angles_deg is not None or truth_root2world is not None):
        raise ValueError("truth_times goes with truth_angles_deg and/or truth_root2world")
    if truth_times is not None:
        tt = _times(truth_times, "truth_times")
        if truth_angles_deg is not None:
            tang = as_array(truth_angles_deg, (len(tt), nj, 3), "truth_angles_deg")
        if truth_root2world is not None:
            tr2w = as_array(truth_root2world, (len(tt), 4, 4), "truth_root2world")
    t0 = 0.0 if release_time_s is None else float(release_time_s)

    def ms(x):
        return (np.asarray(x) - t0) * 1e3

    panels: list[tuple[str, list[tuple[str, np.ndarray | None, np.ndarray | None]]]] = []
    # (panel title, [(label, estimate (n,) or None, truth (m,) or None)])
    wrist = []
    if r2w is not None or tr2w is not None:
        est = _orientation_deg(r2w) if r2w is not None else None
        tru = _orientation_deg(tr2w) if tr2w is not None else None
        for a, name in enumerate(("yaw (about z)", "pitch (about y')", "roll (about x'')")):
            wrist.append((name, None if est is None else est[:, a], None if tru is None else tru[:, a]))
    panels.append(("hand orientation (field frame)", wrist))
    labels = dof_labels(skeleton)
    for d in DIGITS:
        rows = []
        for j, a, lab in labels:
            if _digit(skeleton.names[j]) == d:
                rows.append((lab.split(" ", 1)[1], ang[:, j, a], None if tang is None else tang[:, j, a]))
        panels.append((d, rows))

    fig, axes = plt.subplots(2, 3, figsize=(w / dpi, h / dpi), dpi=dpi, sharex=True)
    cmap = plt.get_cmap("tab10")
    for ax, (name, rows) in zip(axes.ravel(), panels):
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        for k in keys:
            ax.axvline(ms(k), color="0.8", lw=0.6, zorder=0)
        if release_time_s is not None:
            ax.axvline(0.0, color="k", lw=0.8, ls="-.", zorder=0)
        if not rows:
            ax.text(0.5, 0.5, "not given", ha="center", va="center", transform=ax.transAxes, color="0.5")
            continue
        for i, (lab, est, tru) in enumerate(rows):
            c = cmap(i % 10)
            if est is not None:
                ax.plot(ms(t), est, "-", color=c, lw=1.3, label=lab)
                if len(keys) and len(t) > 1:
                    ax.plot(ms(keys), np.interp(keys, t, est, left=np.nan, right=np.nan), "o", ms=4, color=c,
                            mec="k", mew=0.4)
                elif len(keys):
                    ax.plot(ms(t), est, "o", ms=4, color=c, mec="k", mew=0.4)
            if tru is not None:
                ax.plot(ms(tt), tru, "--", color=c, lw=1.0, label=None if est is not None else f"{lab} (truth)")
        ax.legend(fontsize=6, loc="best")
    xl = "time from release (ms)" if release_time_s is not None else "time (ms)"
    for ax in axes[1]:
        ax.set_xlabel(xl, fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("angle (deg)", fontsize=8)
    note = "solid: estimate" + ("; dashed: truth" if tt is not None else "") + ("; dots: flashes" if len(keys) else "")
    fig.suptitle(f"{title} ({note})", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    finally:
        plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------
# HTML report
# --------------------------------------------------------------------------------------------
def _labels_text(labels) -> tuple[str, str]:
    """(count, names) of a flash's labelled markers: a mapping name -> label or a list of names."""
    if labels is None:
        return "", ""
    if isinstance(labels, Mapping):
        names = [f"{k}: {v}" if v not in (None, k) else str(k) for k, v in labels.items()]
    else:
        names = [str(x) for x in labels]
    return str(len(names)), ", ".join(names)


def _release_rows(release: Mapping, truth_release: Mapping | None) -> list[list[str]]:
    def show(x):
        if x is None:
            return ""
        if isinstance(x, (list, tuple, np.ndarray)):
            return "(" + ", ".join(_fmt(float(e), 4) for e in np.ravel(x)) + ")"
        return _fmt(x, 4) if not isinstance(x, str) else x

    rows = []
    for k, v in release.items():
        unit = metric_unit(k)
        if unit == "" and k.endswith("_m"):
            unit = "m"
        row = [k, show(v), unit]
        if truth_release is not None:
            row.append(show(truth_release.get(k)))
        rows.append(row)
    return rows


def _flash_angles(flashes: Sequence[Mapping], nj: int) -> np.ndarray | None:
    if not flashes or all(f.get("angles_deg") is None for f in flashes):
        return None
    out = np.full((len(flashes), nj, 3), np.nan)
    for i, f in enumerate(flashes):
        if f.get("angles_deg") is not None:
            out[i] = as_array(f["angles_deg"], (nj, 3), f"flashes[{i}]['angles_deg']")
    return out


def write_hand_report(folder, *, skeleton: Skeleton | None = None, animation: Animation | None = None,
                      flashes: Sequence[Mapping] = (), release: Mapping | None = None, ball_times=None,
                      ball_positions=None, markers=None, marker_colours=None, truth: Mapping | None = None,
                      release_time_s: float | None = None, animation_format: str = ".gif",
                      animation_options: Mapping | None = None, title: str = "Hand report",
                      messages: Sequence[str] = (), progress: Progress | None = None) -> dict[str, Path]:
    """Write a hand report folder: ``report.html``, ``hand.gif`` (or ``.mp4``) and
    ``joint_angles.png``.

    Parameters
    ----------
    folder : str or PathLike
        Created if missing.
    skeleton : Skeleton, optional
        The hand; default the animation's (one of the two is needed for joint angles).
    animation : Animation, optional
        The hand's motion (e.g. keyframes interpolated at 1000 fps). Gives the animation and
        the joint-angle curves.
    flashes : sequence of mapping
        One per flash, in time order. Keys (all optional but ``time_s``): ``time_s`` (s),
        ``held`` (bool, ball in the hand), ``n_markers`` (markers used by the fit), ``labels``
        (mapping marker name -> label, or a list of the labelled marker names), ``rms_mm`` (fit
        RMS, mm), ``angles_deg`` (n_joints, 3), ``success`` (bool), ``message`` (str).
        Their times are the keyframes.
    release : mapping, optional
        The release summary, ``key -> value`` (numbers, vectors or text); the unit is read from
        the key's suffix (``speed_mph``, ``time_s``, ``position_m`` ...).
    ball_times, ball_positions : array_like, shapes (B,), (B, 3), optional
        The ball (s, m), for the animation.
    markers, marker_colours :
        Glove markers for the animation (see :func:`write_hand_animation`).
    truth : mapping, optional
        Synthetic truth: ``times_s`` (m,), ``angles_deg`` (m, n_joints, 3), ``root2world``
        (m, 4, 4) for dashed curves; ``flash_angles_deg`` (n_flashes, n_joints, 3) for the
        error column of the angle table; ``release`` (mapping like ``release``).
    release_time_s : float, optional
        Times in ms from release.
    animation_format : ``".gif"`` or ``".mp4"``
    animation_options : mapping, optional
        More keywords for :func:`write_hand_animation` (``fps``, ``slowdown``, ``view``, ...).
    title : str
    messages : sequence of str
        Warnings shown at the top.
    progress : callable, optional
        ``progress(done, total, label)`` while the animation renders.

    Returns
    -------
    dict
        ``{"html": Path, "animation": Path, "joint_angles": Path}`` (only the files written).
    """
    out = Path(folder)
    fmt = animation_format if animation_format.startswith(".") else "." + animation_format
    if fmt.lower() not in ANIMATION_FORMATS:
        raise ValueError(f"animation_format must be one of {ANIMATION_FORMATS}, got {animation_format!r}")
    skel = skeleton or (animation.skeleton if animation is not None else None)
    flashes = [dict(f) for f in flashes]
    for i, f in enumerate(flashes):
        if "time_s" not in f:
            raise ValueError(f"flashes[{i}] has no 'time_s'")
    ftimes = np.array([float(f["time_s"]) for f in flashes])
    truth = dict(truth or {})
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}

    if animation is not None:
        opts = dict(animation_options or {})
        opts.setdefault("release_time_s", release_time_s)
        paths["animation"] = write_hand_animation(
            out / f"hand{fmt.lower()}", animation, ball_times=ball_times, ball_positions=ball_positions,
            keyframe_times=ftimes if len(ftimes) else None, markers=markers, marker_colours=marker_colours,
            progress=progress, **opts)

    fang = _flash_angles(flashes, skel.n_joints) if skel is not None else None
    if skel is not None and (animation is not None or fang is not None):
        if animation is not None:
            t, ang, r2w = animation.times, np.array([skel.limit_angles_deg(r) for r in animation.local_rotations]), \
                animation.root2world
        else:
            order = np.argsort(ftimes)
            t, ang, r2w = ftimes[order], fang[order], None
            if all(f.get("root2world") is not None for f in flashes):
                r2w = np.array([flashes[i]["root2world"] for i in order], float)
        tt = truth.get("times_s")
        paths["joint_angles"] = plot_joint_angles(
            out / "joint_angles.png", t, ang, skel, keyframe_times=ftimes if len(ftimes) else None,
            truth_times=tt, truth_angles_deg=truth.get("angles_deg") if tt is not None else None,
            root2world=r2w, truth_root2world=truth.get("root2world") if tt is not None else None,
            release_time_s=release_time_s)

    def tms(x):
        return _fmt(((x - release_time_s) if release_time_s is not None else x) * 1e3, 1)

    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>",
             "<p class='small'>Field frame, metres; times in ms"
             + (" from release" if release_time_s is not None else "") + ". See docs/hand-outputs.md.</p>"]
    for m in messages:
        parts.append(f"<div class='warn'>{html.escape(str(m))}</div>")
    if "animation" in paths:
        name = paths["animation"].name
        if fmt.lower() == ".mp4":
            parts.append(f"<h2>Slow motion</h2><video src='{html.escape(name)}' controls loop muted "
                         "style='max-width:100%'></video>")
        else:
            parts.append(f"<h2>Slow motion</h2><img src='{html.escape(name)}' alt='hand animation'>")
    if release:
        parts.append("<h2>Release</h2>")
        tr = truth.get("release")
        parts.append(_table(["quantity", "value", "unit"] + (["truth"] if tr is not None else []),
                            _release_rows(release, tr)))
    if flashes:
        parts.append("<h2>Flashes</h2>")
        rows = []
        for i, f in enumerate(flashes):
            n_lab, names = _labels_text(f.get("labels"))
            ok = f.get("success")
            status = "" if ok is None else ("ok" if ok else "failed")
            if f.get("message"):
                status = f"{status}: {f['message']}" if status else str(f["message"])
            held = f.get("held")
            rows.append([str(i + 1), tms(f["time_s"]), "" if held is None else ("held" if held else "released"),
                         _fmt(f.get("n_markers")), n_lab, _fmt(f.get("rms_mm"), 2), status, names])
        parts.append(_table(["flash", "time ms", "ball", "markers fitted", "labelled", "fit RMS mm", "status",
                             "labels"], rows))
    if fang is not None:
        parts.append("<h2>Joint angles per flash (degrees)</h2>")
        tfa = truth.get("flash_angles_deg")
        tfa = None if tfa is None else as_array(tfa, fang.shape, "truth['flash_angles_deg']")
        header = ["degree of freedom"] + [f"flash {i + 1}" for i in range(len(flashes))]
        header += ["max |error|"] if tfa is not None else []
        rows = []
        for j, a, lab in dof_labels(skel):
            row = [lab] + [_fmt(fang[i, j, a], 1) for i in range(len(flashes))]
            if tfa is not None:
                err = np.abs(fang[:, j, a] - tfa[:, j, a])
                row.append(_fmt(float(np.nanmax(err)) if np.any(np.isfinite(err)) else float("nan"), 2))
            rows.append(row)
        parts.append(_table(header, rows))
    if "joint_angles" in paths:
        parts.append(f"<h2>Joint angles over time</h2><img src='{html.escape(paths['joint_angles'].name)}' "
                     "alt='joint angles'>")
    parts.append("<p class='small'>stillcap hand outputs.</p></body></html>")
    paths["html"] = write_text(out / "report.html", "\n".join(parts))
    return paths



def write_result_report(result, folder, *, animation_format: str = ".gif", progress: Progress | None = None,
                        truth_arrays: dict | None = None) -> dict[str, Path]:
    """:func:`write_hand_report` for a :class:`~stillcap.pipelines.hand.HandResult`, plus
    ``hand.json`` (the result's :meth:`~stillcap.pipelines.hand.HandResult.to_dict`).

    Times are ms from the estimated release when there is one. With a studio truth in the
    capture (``truth_arrays``: :func:`stillcap.studio.compare.hand.truth_arrays` of it, for a
    result compared with it), the true joint angles are drawn dashed and per-flash errors listed.
    """
    from stillcap.io.project import dumps_json

    out = Path(folder)
    lab, seq, rel = result.labels, result.sequence, result.release
    fits = {int(k): i for i, k in enumerate(seq.flashes)} if seq is not None else {}
    held = result.ball_held()
    flashes, ks = [], []  # ks: the flash index of each entry
    for k in range(lab.n_flashes):
        names = [n for n, p in zip(lab.marker_names, lab.point_index[k]) if p >= 0]
        f = {"time_s": float(lab.times[k]), "labels": names, "n_markers": len(names),
             "rms_mm": float(lab.rms[k] * 1e3), "success": bool(lab.reconstructed[k]), "message": lab.skipped[k]}
        if int(lab.order[k]) in held:
            f["held"] = held[int(lab.order[k])]
        if k in fits:
            f["angles_deg"] = seq.angles_deg[fits[k]]
            f["root2world"] = seq.poses[fits[k]].root2world
        flashes.append(f)
        ks.append(k)
    # the angle table needs every flash: reconstructed ones only
    if any("angles_deg" in f for f in flashes):
        ks = [k for k, f in zip(ks, flashes) if "angles_deg" in f]
        flashes = [f for f in flashes if "angles_deg" in f]
    release = None
    t_rel = None
    if rel is not None and rel.success:
        t_rel = float(rel.t_release)
        release = {"time_s": rel.t_release, "time_sigma_s": rel.t_release_sigma, "speed_mph": rel.speed_mph,
                   "speed_sigma_mph": rel.speed_sigma_mph, "horizontal_deg": rel.horizontal_deg,
                   "vertical_deg": rel.vertical_deg, "direction_sigma_deg": rel.direction_sigma_deg,
                   "position_m": rel.position, "velocity_source": rel.velocity_source}
    truth = None
    tc = result.truth
    td = truth_arrays if tc is not None else None
    if td is not None and np.isfinite(tc.get("clock_offset_s", np.nan)) and seq is not None:
        tr = td
        match = tc["flash_match"]
        fa = np.full((len(flashes),) + tr["angles_deg"].shape[1:], np.nan)
        for i, k in enumerate(ks):
            if match[k] >= 0:
                fa[i] = tr["angles_deg"][match[k]]
        truth = {"times_s": tr["times"] - tc["clock_offset_s"], "angles_deg": tr["angles_deg"],
                 "root2world": tr["root2world"], "flash_angles_deg": fa}
    balls = result.balls
    paths = write_hand_report(
        out, skeleton=result.skeleton, animation=result.animation, flashes=flashes, release=release,
        ball_times=None if balls is None or not len(balls) else balls.times,
        ball_positions=None if balls is None or not len(balls) else balls.positions,
        markers=None, truth=truth, release_time_s=t_rel, animation_format=animation_format,
        title=f"Hand capture {result.capture.root.name if result.capture.root else ''}".strip(),
        messages=result.messages, progress=progress)
    paths["json"] = write_text(out / "hand.json", dumps_json(result.to_dict()) + "\n")
    return paths
