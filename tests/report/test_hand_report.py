"""Hand outputs (stillcap.report.hand): the slow-motion animation (GIF, MP4 where ffmpeg exists),
the joint-angle plot and the HTML report, from the hand studio's truth."""

import re

import cv2
import numpy as np
import pytest
from PIL import Image

import stillcap.report.hand._animation as hand_animation
from stillcap.body import Animation
from stillcap.report.hand import (
    animation_frame_times,
    dof_labels,
    find_ffmpeg,
    plot_joint_angles,
    write_hand_animation,
    write_hand_report,
)
from stillcap.studio.hand import hand_capture

SIZE = (320, 240)
N_FRAMES = 25  # 1000 fps around release: -12 .. +12 ms


@pytest.fixture(scope="module")
def studio():
    """The studio hand (seed 0): a 25-frame Animation at 1000 fps around release, the ball, the
    glove markers, the flashes and the truth."""
    cap = hand_capture(0, image_size=(320, 240), supersample=1)
    m, tr = cap.motion, cap.truth
    t_rel = tr.release.t0
    ts = t_rel + (np.arange(N_FRAMES) - N_FRAMES // 2) * 1e-3
    anim = Animation.from_poses([m.pose(t) for t in ts], ts)
    return {
        "capture": cap,
        "truth": tr,
        "anim": anim,
        "ball_t": ts,
        "ball_p": m.ball2world(ts)[:, :3, 3],
        "markers": cap.markerset.trajectories(anim),
        "release": t_rel,
    }


def _frames(path) -> list[np.ndarray]:
    im = Image.open(path)
    out = []
    for k in range(im.n_frames):
        im.seek(k)
        out.append(np.asarray(im.convert("RGB"), dtype=np.int16))
    return out


def _changed(a, b, top: int = 30) -> float:
    """Share of the pixels below the title whose RGB changed by more than 60 (summed over the
    channels): GIF palettes are chosen per frame, so equal pictures differ by a few levels."""
    return float((np.abs(a - b).sum(axis=-1) > 60)[top:].mean())


def _gif(tmp_path, s, anim=None, name="hand.gif", **kw):
    kw.setdefault("size", SIZE)
    return write_hand_animation(tmp_path / name, anim or s["anim"], ball_times=s["ball_t"], ball_positions=s["ball_p"],
                                markers=s["markers"], release_time_s=s["release"], **kw)


def test_gif_frame_count_size_duration_and_the_hand_moves(tmp_path, studio):
    path = _gif(tmp_path, studio)
    im = Image.open(path)
    assert im.format == "GIF"
    assert im.size == SIZE
    assert im.n_frames == N_FRAMES  # 25 fps x 40 slower = 1 ms per frame = every animation frame
    assert im.info["duration"] == 40  # ms per frame at 25 fps
    frames = _frames(path)
    changed = [_changed(a, b) for a, b in zip(frames, frames[1:])]
    assert min(changed) > 0.003, "two consecutive frames show the same picture"  # measured 0.006-0.010


def test_a_still_hand_gives_still_pictures(tmp_path, studio):
    """Control for the test above: with one pose held, only the title changes."""
    a = studio["anim"]
    still = Animation(a.skeleton, a.times, np.repeat(a.root2world[:1], a.n_frames, 0),
                      np.repeat(a.local_rotations[:1], a.n_frames, 0))
    path = write_hand_animation(tmp_path / "still.gif", still, size=SIZE)
    frames = _frames(path)
    assert len(frames) == N_FRAMES
    assert max(_changed(frames[0], f) for f in frames[1:]) < 0.001  # measured <= 0.0002


def test_glove_markers_in_their_colors_and_flash_frames_highlighted(tmp_path, studio):
    t = studio["anim"].times
    flash = t[6] + 0.0002  # at 2 ms per video frame, the nearest is frame 3
    kw = {"size": (400, 300), "slowdown": 20}
    frames = _frames(_gif(tmp_path, studio, keyframe_times=[flash], **kw))
    assert len(frames) == 13
    title = [f[: int(0.09 * 300)] for f in frames]

    def reddish(img):  # matplotlib's tab:red (214, 39, 40)
        return int((np.abs(img - np.array([214, 39, 40])).sum(axis=-1) < 60).sum())

    assert reddish(title[3]) > 20
    assert all(reddish(title[k]) == 0 for k in range(len(frames)) if k != 3)
    # every glove colour appears on the hand (the marker set's sRGB colours, GIF palette allowed)
    rgb = np.round(studio["capture"].markerset.rgb * 255)
    for c in np.unique(rgb, axis=0):
        near = (np.abs(frames[6] - c).sum(axis=-1) < 45).sum()
        assert near >= 6, f"no marker of colour {c} in the frame"
    # the flash leaves a faint copy behind: later frames differ from a run without the flash
    plain = _frames(_gif(tmp_path, studio, name="plain.gif", **kw))
    changed = [_changed(p, f, 40) for p, f in zip(plain, frames)]
    assert max(changed[:3]) < 0.0005  # measured 0
    assert min(changed[4:]) > 0.001  # measured 0.0018-0.0026


def test_slowdown_fps_and_progress(tmp_path, studio):
    assert len(animation_frame_times(studio["anim"].times, fps=25, slowdown=20)) == 13  # 2 ms per frame
    np.testing.assert_allclose(np.diff(animation_frame_times([0.0, 0.01], fps=10, slowdown=50)), 0.002)
    calls = []
    path = _gif(tmp_path, studio, fps=10, slowdown=20, progress=lambda d, n, label: calls.append((d, n)))
    im = Image.open(path)
    assert im.n_frames == 5  # one frame per 5 ms
    assert im.info["duration"] == 100
    assert calls == [(k, 5) for k in range(1, 6)]


def test_follow_view_and_named_views(tmp_path, studio):
    a = _frames(_gif(tmp_path, studio, name="fixed.gif", slowdown=8))
    b = _frames(_gif(tmp_path, studio, name="follow.gif", slowdown=8, follow=True))
    c = _frames(_gif(tmp_path, studio, name="top.gif", slowdown=8, view="top"))
    assert len(a) == len(b) == len(c) == 5  # one frame per 5 ms over 24 ms
    assert not np.array_equal(a[3], b[3]) and not np.array_equal(a[3], c[3])


def test_mp4_where_ffmpeg_exists(tmp_path, studio):
    if find_ffmpeg() is None:
        pytest.skip("no ffmpeg program (pip install imageio-ffmpeg, or ffmpeg on the PATH): MP4 not tested")
    path = _gif(tmp_path, studio, name="hand.mp4")
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    assert len(frames) == N_FRAMES
    assert frames[0].shape == (SIZE[1], SIZE[0], 3)
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(25)
    assert np.abs(frames[0].astype(int) - frames[-1]).mean() > 0.5


def test_mp4_without_ffmpeg_names_what_to_install(tmp_path, studio, monkeypatch):
    monkeypatch.setattr(hand_animation, "find_ffmpeg", lambda: None)
    with pytest.raises(ImportError, match="pip install imageio-ffmpeg"):
        _gif(tmp_path, studio, name="hand.mp4")
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_leaves_no_temp_and_keeps_the_old_file_on_error(tmp_path, studio):
    path = _gif(tmp_path, studio, slowdown=8)
    old = path.read_bytes()
    assert [p.name for p in tmp_path.iterdir()] == ["hand.gif"]

    def boom(done, total, label):
        if done == 3:
            raise RuntimeError("stop at frame 3")

    with pytest.raises(RuntimeError, match="frame 3"):
        _gif(tmp_path, studio, progress=boom)
    assert path.read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == ["hand.gif"]


def test_animation_bad_input(tmp_path, studio):
    a = studio["anim"]
    with pytest.raises(ValueError, match=r"\.gif or \.mp4.*'\.avi'"):
        write_hand_animation(tmp_path / "x.avi", a)
    with pytest.raises(ValueError, match=r"ball_positions must have shape \(25, 3\), got \(25, 2\)"):
        write_hand_animation(tmp_path / "x.gif", a, ball_times=studio["ball_t"], ball_positions=np.zeros((25, 2)))
    with pytest.raises(ValueError, match="give both or neither"):
        write_hand_animation(tmp_path / "x.gif", a, ball_times=studio["ball_t"])
    with pytest.raises(ValueError, match=r"markers must be MarkerTrajectories or have shape \(25, M, 3\)"):
        write_hand_animation(tmp_path / "x.gif", a, markers=np.zeros((24, 18, 3)))
    with pytest.raises(ValueError, match="one colour per marker"):
        write_hand_animation(tmp_path / "x.gif", a, markers=studio["markers"], marker_colors=["red"])
    with pytest.raises(ValueError, match="view must be one of"):
        write_hand_animation(tmp_path / "x.gif", a, view="under")
    with pytest.raises(ValueError, match="slowdown must be"):
        write_hand_animation(tmp_path / "x.gif", a, slowdown=0)
    with pytest.raises(ValueError, match="even for MP4"):
        write_hand_animation(tmp_path / "x.mp4", a, size=(321, 240))
    with pytest.raises(ValueError, match="must be an Animation"):
        write_hand_animation(tmp_path / "x.gif", a[0])
    assert list(tmp_path.iterdir()) == []


def test_animation_more_bad_input(tmp_path, studio):
    a, bt, bp = studio["anim"], studio["ball_t"], studio["ball_p"]
    with pytest.raises(ValueError, match="ball_times must be strictly increasing"):
        write_hand_animation(tmp_path / "x.gif", a, ball_times=bt[::-1], ball_positions=bp)
    with pytest.raises(ValueError, match="ball_times must be finite"):
        write_hand_animation(tmp_path / "x.gif", a, ball_times=np.where(bt == bt[3], np.nan, bt), ball_positions=bp)
    colors = ["red"] * 17 + ["no-such-colour"]
    with pytest.raises(ValueError, match="marker_colours: 'no-such-colour' is not a colour name or RGB triple"):
        write_hand_animation(tmp_path / "x.gif", a, markers=studio["markers"], marker_colors=colors)
    with pytest.raises(ValueError, match=r"size must be at least 64 x 64 pixels, got \(32, 240\)"):
        write_hand_animation(tmp_path / "x.gif", a, size=(32, 240))
    with pytest.raises(ValueError, match=r"size must be \(width, height\) in pixels"):
        write_hand_animation(tmp_path / "x.gif", a, size=320)
    assert list(tmp_path.iterdir()) == []


# -- joint angles ---------------------------------------------------------------------------
def test_joint_angle_png_has_the_size_asked(tmp_path, studio):
    tr, a = studio["truth"], studio["anim"]
    dense = np.array([a.skeleton.limit_angles_deg(r) for r in a.local_rotations])
    path = plot_joint_angles(tmp_path / "angles.png", tr.times, tr.angles_deg, a.skeleton, keyframe_times=tr.times,
                             truth_times=a.times, truth_angles_deg=dense, root2world=tr.root2world,
                             truth_root2world=a.root2world, release_time_s=studio["release"], size=(900, 600))
    img = cv2.imread(str(path))
    assert img is not None and img.shape == (600, 900, 3)
    assert [p.name for p in tmp_path.iterdir()] == ["angles.png"]
    # the estimate draws something: a plot of other angles is a different picture
    other = plot_joint_angles(tmp_path / "other.png", tr.times, tr.angles_deg + 5.0, a.skeleton, size=(900, 600))
    assert not np.array_equal(cv2.imread(str(other)), img)


def test_dof_labels_cover_the_hand():
    from stillcap.body.hand import hand_dofs, hand_skeleton

    labels = dof_labels(hand_skeleton())
    assert len(labels) == len(hand_dofs(hand_skeleton())) == 21
    assert ("index MCP abduction" in [lab for _, _, lab in labels]) and "thumb CMC twist" in [x[2] for x in labels]


def test_joint_angles_bad_input(tmp_path, studio):
    tr, sk = studio["truth"], studio["anim"].skeleton
    n = len(tr.times)
    with pytest.raises(ValueError, match=rf"angles_deg must have shape \({n}, 21, 3\), got \({n}, 20, 3\)"):
        plot_joint_angles(tmp_path / "a.png", tr.times, tr.angles_deg[:, :20], sk)
    with pytest.raises(ValueError, match="truth_times goes with"):
        plot_joint_angles(tmp_path / "a.png", tr.times, tr.angles_deg, sk, truth_times=tr.times)
    with pytest.raises(ValueError, match="PNG"):
        plot_joint_angles(tmp_path / "a.jpg", tr.times, tr.angles_deg, sk)
    assert list(tmp_path.iterdir()) == []


# -- report -------------------------------------------------------------------------------
def test_report_references_files_that_exist_and_tabulates_flashes(tmp_path, studio):
    tr, a = studio["truth"], studio["anim"]
    names = list(tr.marker_names)
    seen = tr.markers_visible.sum(axis=0) >= 2  # (n_flashes, 18)
    est = tr.angles_deg.copy()
    j = a.skeleton.index("index-mcp")
    est[:, j, 1] += 2.5  # a known error on one degree of freedom
    flashes = [{"time_s": float(t), "held": bool(h), "n_markers": int(seen[i].sum()),
                "labels": [nm for nm, s in zip(names, seen[i]) if s], "rms_mm": 0.25 * (i + 1),
                "angles_deg": est[i], "success": True} for i, (t, h) in enumerate(zip(tr.times, tr.held))]
    release = {"time_s": tr.release.t0, "position_m": tr.release.p0, "speed_mph": tr.release.speed_mph,
               "spin_rpm": tr.release.spin_rpm}
    paths = write_hand_report(
        tmp_path / "rep", animation=a, flashes=flashes, release=release, ball_times=studio["ball_t"],
        ball_positions=studio["ball_p"], markers=studio["markers"], release_time_s=tr.release.t0,
        truth={"flash_angles_deg": tr.angles_deg, "release": release},
        animation_options={"size": SIZE, "slowdown": 8})
    page = paths["html"].read_text()
    refs = re.findall(r"""src=['"]([^'"]+)['"]""", page)
    assert sorted(refs) == ["hand.gif", "joint_angles.png"]
    for r in refs:
        assert (tmp_path / "rep" / r).is_file()
    assert Image.open(tmp_path / "rep" / "hand.gif").n_frames == 5
    assert cv2.imread(str(paths["joint_angles"])) is not None
    assert sorted(p.name for p in (tmp_path / "rep").iterdir()) == ["hand.gif", "joint_angles.png", "report.html"]
    # per-flash rows: time from release, RMS, the number of labelled markers
    for i, f in enumerate(flashes):
        row = re.search(rf"<tr><td>{i + 1}</td><td class=\"n\">([^<]*)</td>.*?</tr>", page)
        assert row, f"flash {i + 1} row missing"
        assert row.group(1) == f"{(f['time_s'] - tr.release.t0) * 1e3:.1f}"
        assert f"<td class=\"n\">{f['rms_mm']:.2f}</td>" in row.group(0)
        assert f"<td class=\"n\">{len(f['labels'])}</td>" in row.group(0)
    # the angle table: each flash's value, and the error column sees the 2.5 deg offset only there
    row = re.search(r"<tr><td>index MCP flexion</td>(.*?)</tr>", page).group(1)
    cells = re.findall(r">([^<]*)</td>", row)
    assert cells[:-1] == [f"{v:.1f}" for v in est[:, j, 1]]
    assert cells[-1] == "2.50"
    other = re.search(r"<tr><td>middle MCP flexion</td>(.*?)</tr>", page).group(1)
    assert re.findall(r">([^<]*)</td>", other)[-1] == "0.00"
    assert f"{tr.release.speed_mph:.4f}" in page


def test_report_without_animation_plots_flash_angles(tmp_path, studio):
    tr, sk = studio["truth"], studio["anim"].skeleton
    flashes = [{"time_s": float(t), "angles_deg": ang, "root2world": r} for t, ang, r in
               zip(tr.times, tr.angles_deg, tr.root2world)]
    paths = write_hand_report(tmp_path, skeleton=sk, flashes=flashes)
    assert set(paths) == {"html", "joint_angles"}
    assert "<img" in paths["html"].read_text() and "hand.gif" not in paths["html"].read_text()
    with pytest.raises(ValueError, match="time_s"):
        write_hand_report(tmp_path / "x", skeleton=sk, flashes=[{"rms_mm": 1.0}])
    with pytest.raises(ValueError, match="animation_format"):
        write_hand_report(tmp_path / "x", animation_format="avi")


def test_the_animation_frames_the_hand_not_the_ball_flight(studio, tmp_path, monkeypatch):
    """The GIF showed the hand as a tiny cluster in an empty box: its limits took in the ball's
    whole flight. They now hold the hand (joints and markers) over the take with a margin, with
    equal scales on the three axes."""
    from stillcap.report.hand import animation_limits

    joints = studio["anim"].positions
    markers = studio["markers"].points
    center, half = animation_limits(joints, markers)
    hand = np.concatenate([joints.reshape(-1, 3), markers.reshape(-1, 3)])
    hand = hand[np.all(np.isfinite(hand), axis=1)]
    size = np.max(np.ptp(joints, axis=1))  # the hand's largest extent in one frame
    assert np.all(hand >= center - half) and np.all(hand <= center + half)  # every joint and marker inside
    margin = half - 0.5 * np.ptp(hand, axis=0)
    assert np.allclose(margin, 0.25 * size + hand_animation._BALL_RADIUS)  # the same margin on every axis
    # the GIF's axes are these limits, with a ball that flies 2 m on (clipped, it does not set them)
    figs = []
    real_close = hand_animation.plt.close
    monkeypatch.setattr(hand_animation.plt, "close", lambda fig: figs.append(fig))
    t, p = studio["ball_t"], studio["ball_p"].copy()
    p[-1] += (0.0, -2.0, 0.0)
    write_hand_animation(tmp_path / "a.gif", studio["anim"], ball_times=t, ball_positions=p,
                         markers=studio["markers"], size=SIZE)
    (fig,) = figs
    ax = fig.axes[0]
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    real_close(fig)
    assert np.allclose(lims[:, 0], center - half) and np.allclose(lims[:, 1], center + half)
    aspect = np.asarray(ax.get_box_aspect())
    assert np.allclose(aspect / aspect.max(), half / half.max())  # equal scales: the box has the data's shape
    # the follow view: a cube around the hand's size
    _, cube = animation_limits(joints, markers, follow=True)
    assert np.allclose(cube, cube[0]) and cube[0] == pytest.approx(0.75 * size + hand_animation._BALL_RADIUS)
    with pytest.raises(ValueError, match="every joint position is NaN"):
        animation_limits(np.full((3, 4, 3), np.nan))
