"""Take turntable photos from a camera (or a video file) straight into a puppet project.

The thesis's GUI showed the live webcam stream and took one photo per turn angle. Here
:func:`capture_turntable` opens ``cv2.VideoCapture(source)`` (a camera index, or a video file so
it can be tested and replayed), asks ``prompt(angle_deg)`` before each angle (the CLI says "turn
the table to 30 deg and press Enter"), grabs a frame (optionally the mean of several, which
lowers sensor noise by sqrt(n) on a still scene), and stores it in the project as the view at
that angle, saving the project after every photo so an interrupted session keeps what it took.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import cv2
import numpy as np

from stillcap.io.project import Project, View
from stillcap.io.project._records import _same_angle

__all__ = ["Answer", "SKIP", "ABORT", "CAMERA_DISCARD_FRAMES", "CaptureResult", "capture_turntable",
           "open_source", "grab_frame", "parse_angles"]


class Answer(enum.Enum):
    """What ``prompt`` may return besides None/True (take the photo)."""

    SKIP = "skip"    #: leave this angle out, go on with the next
    ABORT = "abort"  #: stop; photos already taken stay in the project


SKIP = Answer.SKIP
ABORT = Answer.ABORT

#: Frames thrown away before each photo from a live camera: its driver buffers a few frames,
#: and without this the "photo" would show the table before it was turned.
CAMERA_DISCARD_FRAMES = 5


@dataclass
class CaptureResult:
    """What :func:`capture_turntable` did.

    Attributes
    ----------
    views : list of View
        The views added (or retaken), in capture order.
    skipped_deg : list of float
        Angles the prompt skipped, degrees.
    aborted : bool
        The prompt stopped the session before the last angle.
    """

    views: list[View] = field(default_factory=list)
    skipped_deg: list[float] = field(default_factory=list)
    aborted: bool = False

    @property
    def captured_deg(self) -> list[float]:
        """Angles photographed, degrees."""
        return [v.angle_deg for v in self.views]


def parse_angles(spec: str) -> list[float]:
    """Turn angles in degrees from a command-line spec.

    ``"12x30"``: 12 angles 30 degrees apart from 0 (0, 30, ..., 330); ``"4x90@45"``: starting
    at 45; ``"0,30,90"``: a list; ``"30"``: one angle.
    """
    s = str(spec).replace(" ", "")
    m = re.fullmatch(r"(\d+)[xX]([-+]?\d+(?:\.\d*)?)(?:@([-+]?\d+(?:\.\d*)?))?", s)
    if m:
        n, step, start = int(m.group(1)), float(m.group(2)), float(m.group(3) or 0.0)
        if n < 1 or step == 0:
            raise ValueError(f"angles {spec!r}: need at least one angle and a non-zero step")
        return [start + i * step for i in range(n)]
    try:
        out = [float(p) for p in s.split(",") if p]
    except ValueError:
        raise ValueError(f"angles {spec!r}: use NxSTEP (12x30), NxSTEP@START (4x90@45) or a list (0,30,90), "
                         "all in degrees") from None
    if not out or not all(math.isfinite(a) for a in out):
        raise ValueError(f"angles {spec!r}: no finite angles given")
    return out


def open_source(source):
    """Open a camera index, a video file or pass through an opened capture-like object.

    Returns
    -------
    capture, description, owned
        ``owned`` is True when this function opened it (the caller must release it).
    """
    if hasattr(source, "read") and not isinstance(source, (str, Path)):
        return source, f"video source {type(source).__name__}", False
    if isinstance(source, (int, np.integer)) and not isinstance(source, bool):
        desc = f"camera {int(source)}"
        cap = cv2.VideoCapture(int(source))
    elif isinstance(source, (str, Path)):
        p = Path(source)
        if str(source).isdigit() and not p.exists():
            return open_source(int(source))
        desc = f"video file {p}"
        if not p.is_file():
            raise ValueError(f"{desc} does not exist")
        cap = cv2.VideoCapture(str(p))
    else:
        raise ValueError(f"source must be a camera index (int) or a video file path, got {source!r}")
    if not cap.isOpened():
        cap.release()
        raise ValueError(f"could not open {desc}" + (" (no such camera, or it is in use)" if desc.startswith("camera")
                                                     else " (not a video OpenCV can decode)"))
    return cap, desc, True


def grab_frame(cap, frames_to_average: int = 1, discard_frames: int = 0, what: str = "video source") -> np.ndarray:
    """Read one frame (BGR uint8), or the rounded mean of ``frames_to_average`` consecutive frames.

    Raises
    ------
    ValueError
        ``what`` delivered no frame (end of a video file, camera unplugged) or frames of
        changing size.
    """
    for _ in range(int(discard_frames)):
        if not cap.grab():
            raise ValueError(f"no frame could be read from {what} (end of the video, or the camera stopped)")
    acc = None
    for k in range(int(frames_to_average)):
        ok, frame = cap.read()
        if not ok or frame is None:
            raise ValueError(f"no frame could be read from {what} (end of the video, or the camera stopped)"
                             + (f" after {k} of {frames_to_average} frames to average" if k else ""))
        if frame.dtype != np.uint8:
            raise ValueError(f"{what} delivers {frame.dtype} frames; 8-bit frames are needed")
        if acc is None:
            acc = frame.astype(np.float64)
        elif frame.shape != acc.shape:
            raise ValueError(f"{what} changed its frame size while averaging ({acc.shape} -> {frame.shape})")
        else:
            acc += frame
    if frames_to_average == 1:
        return acc.astype(np.uint8)
    return np.clip(np.rint(acc / frames_to_average), 0, 255).astype(np.uint8)


def capture_turntable(project: Project, source, angles_deg: Sequence[float],
                      prompt: Callable[[float], object] | None = None, frames_to_average: int = 1, *,
                      discard_frames: int | None = None, replace: bool = False,
                      detect: Callable[[np.ndarray], Mapping] | None = None,
                      image_suffix: str = ".png") -> CaptureResult:
    """Photograph the puppet at each turn angle into a turntable project.

    Parameters
    ----------
    project : Project
        A turntable project; each photo becomes its view at that angle and the project is saved
        after each photo (atomically).
    source : int, path or capture-like
        Camera index for ``cv2.VideoCapture``, a video file, or an opened object with
        ``read()``/``grab()`` (not released here).
    angles_deg : sequence of float
        Turn angles in degrees, in the order to take them (:func:`parse_angles` reads ``12x30``).
    prompt : callable, optional
        ``prompt(angle_deg)`` before each photo (turn the table, press Enter). Return None or
        True to take it, :data:`SKIP` to leave this angle out, False or :data:`ABORT` to stop.
    frames_to_average : int
        Frames averaged per photo (a still scene: the mean lowers noise).
    discard_frames : int, optional
        Frames dropped before each photo (default: :data:`CAMERA_DISCARD_FRAMES` for a camera,
        0 for a video file or object).
    replace : bool
        Retake angles the project already has (otherwise that is an error, raised before the
        source is opened).
    detect : callable, optional
        ``detect(image) -> {marker: (x, y)}``: automatic detections stored with each photo.
    image_suffix : str
        ``.png`` (lossless, default) or ``.jpg``.

    Raises
    ------
    ValueError
        Not a turntable project, bad angles, existing angles without ``replace``, the source
        cannot be opened (named), no frame could be read, or the frame size differs from the
        project camera's. Photos taken before the error stay saved in the project.
    """
    if not isinstance(project, Project) or not project.is_turntable:
        raise ValueError("capture_turntable needs a turntable project (Project.create(folder, turntable=...))")
    angles = [float(a) for a in angles_deg]
    if not angles:
        raise ValueError("no turn angles given")
    bad = [a for a in angles if not math.isfinite(a)]
    if bad:
        raise ValueError(f"turn angles must be finite numbers of degrees, got {bad}")
    for i, a in enumerate(angles):
        if any(_same_angle(a, b) for b in angles[:i]):
            raise ValueError(f"turn angle {a:g} deg is listed twice (angles are modulo 360)")
    if isinstance(frames_to_average, bool) or int(frames_to_average) != frames_to_average or frames_to_average < 1:
        raise ValueError(f"frames_to_average must be a whole number >= 1, got {frames_to_average}")
    frames_to_average = int(frames_to_average)
    if not replace:
        taken = [a for a in angles if project.view_at(a) is not None]
        if taken:
            raise ValueError(f"the project already has photos at {', '.join(f'{a:g}' for a in taken)} deg; "
                             "pass replace=True to retake them")
    w, h = project.turntable.camera.image_size
    cap, desc, owned = open_source(source)

    def size_error(fw, fh):
        return ValueError(f"{desc} delivers {fw}x{fh} px frames but the project's camera "
                          f"{project.turntable.camera.name!r} is {w}x{h} px (calibrate at this size or set "
                          "the camera's resolution)")

    try:
        if discard_frames is None:
            discard_frames = CAMERA_DISCARD_FRAMES if desc.startswith("camera") else 0
        if owned and desc.startswith("camera"):
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, w)  # ask for the calibrated size; checked on every frame
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
        if owned:  # what the backend reports, checked before the user turns the table for nothing
            rw, rh = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            if rw > 0 and rh > 0 and (rw, rh) != (w, h):
                raise size_error(rw, rh)
        result = CaptureResult()
        for a in angles:
            answer = prompt(a) if prompt is not None else None
            if answer is False or answer is ABORT:
                result.aborted = True
                break
            if answer is SKIP:
                result.skipped_deg.append(a)
                continue
            frame = grab_frame(cap, frames_to_average, discard_frames, desc)
            if frame.shape[:2] != (h, w):
                raise size_error(frame.shape[1], frame.shape[0])
            detections = detect(frame) if detect is not None else None
            view = project.add_view(frame, angle_deg=a, detections=detections, replace=replace,
                                    image_suffix=image_suffix)
            project.save()
            result.views.append(view)
        return result
    finally:
        if owned:
            cap.release()
