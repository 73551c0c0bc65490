"""The slow-motion animation of the hand and the ball, GIF or MP4 (:func:`write_hand_animation`)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import animation as mpl_animation  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from stillcap._checks import as_array, as_positive  # noqa: E402
from stillcap.ball.layout import BASEBALL_RADIUS as _BALL_RADIUS  # noqa: E402
from stillcap.body.skeleton import Animation  # noqa: E402
from stillcap.files.atomic import atomic_path  # noqa: E402
from stillcap.report.hand._common import (ANIMATION_FORMATS, _DIGIT_COLORS, Progress, _bone_groups,  # noqa: E402
                                          _interp, _marker_input, _marker_rgb, _segments, _size, _time_text,
                                          _times, _view, animation_frame_times, find_ffmpeg)


# --------------------------------------------------------------------------------------------
# animation
# --------------------------------------------------------------------------------------------
def animation_limits(joints, markers=None, *, ball_radius: float = _BALL_RADIUS,
                     follow: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The animation's axes: ``(center, half_size)``, each shape (3,), metres.

    Fixed (``follow`` False): the hand's extent (joints and markers) over the whole take, plus
    a quarter of the hand's size and the ball's radius on each side; the ball is not included
    (it flies on out of the box, clipped: framing its whole flight made the hand a tiny cluster
    in an empty box). ``follow``: a cube of the hand's largest extent in one frame times 1.5,
    plus the ball's radius (its centre moves with the hand; ``center`` is then the take's).

    Parameters
    ----------
    joints : ndarray, shape (n_frames, n_joints, 3)
    markers : ndarray, shape (n_frames, n_markers, 3), optional
        NaN where unseen.
    """
    every = [np.asarray(joints, float).reshape(-1, 3)]
    if markers is not None:
        every.append(np.asarray(markers, float).reshape(-1, 3))
    hand = np.concatenate(every)
    hand = hand[np.all(np.isfinite(hand), axis=1)]
    if not len(hand):
        raise ValueError("nothing to draw: every joint position is NaN")
    j = np.asarray(joints, float)
    seen = j[np.isfinite(j).all(axis=2).any(axis=1)]  # frames with a joint (an all-NaN one has no size)
    size = float(np.nanmax(np.nanmax(seen, axis=1) - np.nanmin(seen, axis=1))) if len(seen) else 0.0
    size = max(size if np.isfinite(size) else 0.0, 0.05)
    if follow:
        half = np.full(3, 0.5 * size * 1.5 + ball_radius)
    else:
        half = 0.5 * np.ptp(hand, axis=0) + 0.25 * size + ball_radius
    return 0.5 * (hand.min(axis=0) + hand.max(axis=0)), half


def write_hand_animation(path, animation: Animation, *, ball_times=None, ball_positions=None, keyframe_times=None,
                         markers=None, marker_colors=None, fps: float = 25.0, slowdown: float = 40.0,
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
        One colour per marker: a glove colour name (:data:`~stillcap.body.hand.HAND_COLORS`),
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
        False: fixed limits around the hand (joints and markers) over the whole take, plus a
        margin, with equal scales on the three axes; the ball is drawn where it is inside them.
        True: a cube of fixed size (the hand's largest extent plus a margin) centred on the
        hand in each frame, to see the fingers.
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
        mrgb = _marker_rgb(mnames, marker_colors)
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

    fixed_center, half_box = animation_limits(joints, mvid, ball_radius=ball_radius, follow=follow)

    fig = plt.figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 0.9), projection="3d")
    ax.view_init(elev=elev, azim=azim)
    ax.set_box_aspect(tuple(half_box / half_box.max()), zoom=1.12)  # equal aspect; zoom fills the figure
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7, labelpad=8)
    ax.set_zlabel("z (m)", fontsize=7, labelpad=8)
    ax.zaxis.set_rotate_label(False)  # upright (matplotlib turns it upside down on the left)
    ax.zaxis.label.set_rotation(90)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):  # few ticks: a narrow side of the box shows no overlapping labels
        axis.set_major_locator(MaxNLocator(4))
    ax.tick_params(labelsize=6)
    heading = fig.text(0.5, 0.955, "", ha="center", va="center", fontsize=10)
    fig.text(0.5, 0.91, "field frame, metres" + (f"; {slowdown:g}x slower" if slowdown != 1 else ""),
                   ha="center", va="center", fontsize=7, color="0.4")

    skel = animation.skeleton
    groups = _bone_groups(skel)
    clip = {"axlim_clip": True}  # the box hides what leaves it (the ball after release)
    bone_lines = {g: ax.plot([], [], [], "-", lw=2.0, color=_DIGIT_COLORS.get(g, "0.25"), solid_capstyle="round",
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

    def set_limits(center):
        ax.set_xlim(center[0] - half_box[0], center[0] + half_box[0])
        ax.set_ylim(center[1] - half_box[1], center[1] + half_box[1])
        ax.set_zlim(center[2] - half_box[2], center[2] + half_box[2])

    set_limits(fixed_center)

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
            set_limits(c if np.all(np.isfinite(c)) else fixed_center)
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
