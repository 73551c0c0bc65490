"""Turntable capture from a video source into a project (a video file stands in for the webcam)."""

import cv2
import numpy as np
import pytest

from stillcap.camera import Camera, Rig
from stillcap.io.camera_capture import ABORT, SKIP, capture_turntable, grab_frame, open_source, parse_angles
from stillcap.io.project import Project

W, H = 640, 480


def drawn_frame(k, size=(W, H)):
    """Smooth content (MJPG keeps it well): a gradient, a disc that moves with k, a bar."""
    w, h = size
    y, x = np.mgrid[0:h, 0:w]
    img = np.dstack([(x * 200 / w + 20 * k) % 256, (y * 200 / h) % 256, np.full((h, w), 60 + 30 * k)]).astype(np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 2)
    cv2.circle(img, (w // 4 + 60 * k, h // 2), h // 8, (40, 40 + 40 * k, 220), -1, cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), 1.5)


def write_video(path, n=6, size=(W, H)):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, size)
    assert writer.isOpened()
    frames = [drawn_frame(k, size) for k in range(n)]
    for f in frames:
        writer.write(f)
    writer.release()
    return frames


def decoded_frames(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        out.append(f)
    cap.release()
    return out


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "turn.avi"
    drawn = write_video(path)
    return path, drawn, decoded_frames(path)


@pytest.fixture
def project(tmp_path):
    return Project.create(tmp_path / "proj")


def test_captures_one_photo_per_angle(video, project):
    path, drawn, decoded = video
    asked = []

    def prompt(angle):
        asked.append(angle)  # the CLI asks the user to turn the table and press Enter

    result = capture_turntable(project, path, [0, 30, 60], prompt=prompt)
    assert asked == [0.0, 30.0, 60.0]
    assert result.captured_deg == [0.0, 30.0, 60.0] and not result.aborted and result.skipped_deg == []
    q = Project.load(project.root)  # saved
    assert q.angles_deg == [0.0, 30.0, 60.0]
    for k, v in enumerate(q.views):
        img = q.read_image(v)
        assert np.array_equal(img, decoded[k])  # stored losslessly: exactly the frame the camera gave
        assert np.abs(img.astype(int) - drawn[k]).mean() < 3  # and that is the scene, within codec loss


def test_averages_frames(video, project):
    path, _, decoded = video
    capture_turntable(project, path, [0, 90], frames_to_average=2)
    for k, v in enumerate(project.views):
        mean = np.rint((decoded[2 * k].astype(float) + decoded[2 * k + 1]) / 2).astype(np.uint8)
        assert np.array_equal(project.read_image(v), mean)


def test_skip_and_abort(video, project):
    path, _, decoded = video
    answers = iter([None, SKIP, True, ABORT])
    result = capture_turntable(project, path, [0, 30, 60, 90, 120], prompt=lambda a: next(answers))
    assert result.captured_deg == [0.0, 60.0] and result.skipped_deg == [30.0] and result.aborted
    assert np.array_equal(project.read_image(1), decoded[1])  # a skipped angle reads no frame
    result = capture_turntable(project, path, [90], prompt=lambda a: False)
    assert result.aborted and result.views == []
    assert Project.load(project.root).angles_deg == [0.0, 60.0]


def test_detections_and_retakes(video, project):
    path, _, decoded = video
    capture_turntable(project, path, [0], detect=lambda img: {"head.1": (10.0, 20.0)})
    assert project.views[0].detected == {"head.1": (10.0, 20.0)}
    old = project.root / project.views[0].image
    with pytest.raises(ValueError, match=r"already has photos at 0 deg; pass replace=True"):
        capture_turntable(project, path, [0, 30])
    capture_turntable(project, cv2.VideoCapture(str(path)), [0], replace=True, discard_frames=3)
    assert np.array_equal(project.read_image(0), decoded[3]) and project.views[0].detected == {}
    assert not old.exists()


def test_source_errors(tmp_path, project):
    with pytest.raises(ValueError, match=r"video file .*nope.avi does not exist"):
        capture_turntable(project, tmp_path / "nope.avi", [0])
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"this is not a video")
    with pytest.raises(ValueError, match=r"could not open video file .*junk.avi"):
        capture_turntable(project, junk, [0])
    with pytest.raises(ValueError, match=r"could not open camera 97"):
        capture_turntable(project, 97, [0])
    with pytest.raises(ValueError, match="camera index"):
        open_source(3.5)
    assert project.views == []


def test_end_of_video_keeps_what_was_taken(tmp_path, project):
    path = tmp_path / "short.avi"
    write_video(path, n=2)
    with pytest.raises(ValueError, match=r"no frame could be read from video file .*short.avi"):
        capture_turntable(project, path, [0, 30, 60])
    assert Project.load(project.root).angles_deg == [0.0, 30.0]


def test_frame_size_must_match_the_camera(tmp_path, project):
    path = tmp_path / "small.avi"
    write_video(path, n=2, size=(320, 240))
    asked = []
    with pytest.raises(ValueError, match=r"delivers 320x240 px frames but the project's camera 'webcam' is 640x480 px"):
        capture_turntable(project, path, [0], prompt=asked.append)
    assert asked == []  # found before the user is asked to turn the table
    with pytest.raises(ValueError, match=r"delivers 320x240 px frames"):  # a reader that does not report its size
        capture_turntable(project, cv2.VideoCapture(str(path)), [0])
    assert project.views == []


def test_argument_errors(video, tmp_path, project):
    path = video[0]
    with pytest.raises(ValueError, match="listed twice"):
        capture_turntable(project, path, [0, 360])
    with pytest.raises(ValueError, match="frames_to_average"):
        capture_turntable(project, path, [0], frames_to_average=0)
    with pytest.raises(ValueError, match="no turn angles"):
        capture_turntable(project, path, [])
    rig = Rig([Camera.from_intrinsics("a", 800, 800, 320, 240, (W, H))])
    with pytest.raises(ValueError, match="needs a turntable project"):
        capture_turntable(Project.create(tmp_path / "rigp", rig=rig), path, [0])


def test_grab_frame_from_any_reader():
    class Fake:
        def __init__(self):
            self.k = 0

        def grab(self):
            self.k += 1
            return True

        def read(self):
            self.k += 1
            return True, np.full((2, 2, 3), self.k, np.uint8)

    assert grab_frame(Fake(), 2, discard_frames=1)[0, 0, 0] == 2  # mean of 2 and 3, rounded half to even


def test_parse_angles():
    assert parse_angles("12x30") == [30.0 * k for k in range(12)]
    assert parse_angles("4x90@45") == [45.0, 135.0, 225.0, 315.0]
    assert parse_angles("0, 30,90") == [0.0, 30.0, 90.0]
    assert parse_angles("22.5") == [22.5]
    with pytest.raises(ValueError, match="use NxSTEP"):
        parse_angles("twelve")
    with pytest.raises(ValueError, match="non-zero step"):
        parse_angles("3x0")
