"""Finding calibration targets in photos: chessboards, ChArUco boards, calibration objects.

Detection is kept apart from solving: every detector returns a :class:`Detection` holding 2D-3D
point correspondences (``object_points`` in the target's frame, metres; ``image_points`` in
pixels, ``(x, y)``, origin at the centre of the top-left pixel), and the solvers in
:mod:`~stillcap.calibrate.intrinsics` and :mod:`~stillcap.calibrate.extrinsics` work on those
correspondences only. A photo where the target is not found gives a :class:`Detection` with
``success=False`` and the reason, never an exception; a file that cannot be read raises
``ValueError`` naming it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard
from stillcap.files.images import read_image

#: ``progress(done, total, name)``, called after each image of a long loop (for progress bars).
Progress = Callable[[int, int, str], None]

# cornerSubPix stopping rule of OpenCV's calibration sample: 30 iterations or a 0.001 px move.
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


@dataclass
class Detection:
    """2D-3D correspondences of one target in one image.

    Attributes
    ----------
    name : str
        Image name (file name, or ``"#i"`` for in-memory images).
    image_size : (width, height) in pixels.
    object_points : ndarray, shape (N, 3)
        Target points in the target frame (metres).
    image_points : ndarray, shape (N, 2)
        Their pixels.
    ids : ndarray, shape (N,)
        Point ids: chessboard corner index, ChArUco corner id, or for a calibration object the
        corner id offset by the corner counts of the faces before it.
    success : bool
        Whether the target was found; if not, ``reason`` says why and the arrays are empty.
    """

    name: str
    image_size: tuple[int, int]
    object_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    image_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    success: bool = True
    reason: str = ""

    @classmethod
    def failed(cls, name: str, image_size, reason: str) -> Detection:
        return cls(name, tuple(image_size), success=False, reason=reason)


# --- images -------------------------------------------------------------------------------
def image_name(image, index: int) -> str:
    """File name of a path, or ``"#index"`` for an in-memory image."""
    return Path(image).name if isinstance(image, (str, Path)) else f"#{index}"


def read_gray(image, name: str | None = None) -> np.ndarray:
    """An image as 8-bit grey.

    Parameters
    ----------
    image : path or ndarray, shape (H, W) or (H, W, 3) (BGR) or (H, W, 4)
        Float images are taken as 0..1, uint16 as 0..65535.
    name : used in error messages.

    Raises
    ------
    ValueError
        The file does not exist or cannot be decoded, or the array is not an image.
    """
    if isinstance(image, (str, Path)):
        return read_image(image, cv2.IMREAD_GRAYSCALE)  # size and completeness checked before decoding
    a = np.asarray(image)
    label = name or "image"
    if a.ndim == 3 and a.shape[2] in (3, 4):
        a = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY if a.shape[2] == 3 else cv2.COLOR_BGRA2GRAY) \
            if a.dtype == np.uint8 else a[..., :3].mean(axis=2)
    if a.ndim != 2 or min(a.shape) < 2:
        raise ValueError(f"{label} must have shape (H, W) or (H, W, 3), got {np.shape(image)}")
    if a.dtype == np.uint8:
        return a
    if a.dtype == np.uint16:
        return (a >> 8).astype(np.uint8)
    if np.issubdtype(a.dtype, np.floating) or a.dtype == bool:
        a = a.astype(float)
        if a.max(initial=0) <= 1.0:
            a = a * 255
    return np.clip(np.rint(a), 0, 255).astype(np.uint8)


# --- chessboards --------------------------------------------------------------------------
def find_chessboard(gray: np.ndarray, board: Chessboard, fallback_sb: bool = True,
                    canonical: bool = True) -> np.ndarray | None:
    """Inner corners ``(cols*rows, 2)`` of a chessboard, or None.

    ``cv2.findChessboardCorners`` + ``cv2.cornerSubPix`` (11x11 window, OpenCV's sample
    criteria), with ``cv2.findChessboardCornersSB`` as a fallback. With ``canonical`` and a
    board whose ``cols + rows`` is odd (then a 180-degree turn changes the colours), the order
    is made consistent with the printed board: the square diagonally outside corner 0 is black
    (as in :meth:`Chessboard.texture`). OpenCV may otherwise return either order, which does not
    matter for intrinsics but does for poses shared between cameras.
    """
    size = board.pattern_size
    ok, corners = cv2.findChessboardCorners(gray, size)
    if ok:
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), SUBPIX_CRITERIA)
    elif fallback_sb:
        ok, corners = cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_ACCURACY)
    if not ok:
        return None
    c = corners.reshape(-1, 2).astype(float)
    if canonical and (board.cols + board.rows) % 2 == 1:
        c = _canonical_order(gray, c, board.cols)
    return c


def _canonical_order(gray: np.ndarray, c: np.ndarray, cols: int) -> np.ndarray:
    # Compares the first and the last square inside the corner grid (black and white on the
    # printed board when cols + rows is odd); no OpenCV function does this for the classic
    # detector. A 3x3 patch at the mean of each square's four corners is robust to perspective.
    def shade(quad):
        x, y = np.rint(c[quad].mean(axis=0)).astype(int)
        return float(gray[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].mean())

    n = len(c)
    first = shade([0, 1, cols, cols + 1])
    last = shade([n - 1, n - 2, n - 1 - cols, n - 2 - cols])
    return c[::-1].copy() if first > last else c


# --- ChArUco ------------------------------------------------------------------------------
def _aruco_markers(gray: np.ndarray, dictionary: int):
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(dictionary),
                                  cv2.aruco.DetectorParameters())
    corners, ids, _ = det.detectMarkers(gray)
    return corners, ids


def find_charuco(gray: np.ndarray, target: CharucoTarget, markers=None) -> tuple[np.ndarray, np.ndarray]:
    """ChArUco corners of one board: ``ids (N,)`` and pixels ``(N, 2)`` (N may be 0).

    ``markers`` = ``(corners, ids)`` from ``cv2.aruco.ArucoDetector.detectMarkers`` lets several
    boards share one marker detection (markers of other boards are ignored).
    """
    det = cv2.aruco.CharucoDetector(target.board())
    if markers is None:
        cc, ci, _, _ = det.detectBoard(gray)
    else:
        mc, mi = markers
        if mi is None or len(mi) == 0:
            return np.zeros(0, int), np.zeros((0, 2))
        cc, ci, _, _ = det.detectBoard(gray, markerCorners=mc, markerIds=mi)
    if cc is None or ci is None or len(ci) == 0:
        return np.zeros(0, int), np.zeros((0, 2))
    return ci.ravel().astype(int), _refine_charuco(gray, cc.reshape(-1, 2), target)


def _refine_charuco(gray: np.ndarray, px: np.ndarray, target: CharucoTarget) -> np.ndarray:
    # CharucoDetector's own corners are often off by 0.2-0.4 px on clean synthetic renderings;
    # one more cornerSubPix with a window about the white gap between corner and markers
    # (half-size 3..5 px) cut the mean error over 36 test views from 0.12 to 0.09 px and the
    # worst view from 0.56 to 0.29 px (OpenCV 5.0).
    if len(px) < 2:
        return px.astype(float)
    d = np.linalg.norm(px[:, None] - px[None], axis=2)
    np.fill_diagonal(d, np.inf)
    square_px = float(np.median(d.min(axis=1)))
    gap_px = square_px * (target.square - target.marker) / (2 * target.square)
    half = int(np.clip(np.floor(0.8 * gap_px), 3, 5))
    c = px.astype(np.float32).reshape(-1, 1, 2)
    return cv2.cornerSubPix(gray, c, (half, half), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2).astype(float)


# --- any target ---------------------------------------------------------------------------
def detect_target(image, target, name: str | None = None, min_corners: int = 6) -> Detection:
    """Find ``target`` in one image.

    Parameters
    ----------
    image : path or ndarray (grey or BGR)
    target : Chessboard, CharucoTarget or CalibrationObject (ChArUco faces with disjoint ids)
    name : image name for results and messages (default: the file name, or ``"image"``).
    min_corners : fewest ChArUco corners accepted per image (per object for a calibration object).

    Returns
    -------
    Detection
        ``success=False`` with a reason when the target is not found.
    """
    if name is None:
        name = Path(image).name if isinstance(image, (str, Path)) else "image"
    gray = read_gray(image, name)
    size = (gray.shape[1], gray.shape[0])
    if isinstance(target, Chessboard):
        c = find_chessboard(gray, target)
        if c is None:
            return Detection.failed(name, size, f"{target.cols}x{target.rows} chessboard not found")
        return Detection(name, size, target.object_points(), c, np.arange(len(c)))
    if isinstance(target, CharucoTarget):
        ids, px = find_charuco(gray, target)
        if len(ids) < min_corners:
            return Detection.failed(name, size, f"only {len(ids)} ChArUco corners found (need {min_corners})")
        return Detection(name, size, target.object_points()[ids], px, ids)
    if isinstance(target, CalibrationObject):
        return _detect_object(gray, target, name, size, min_corners)
    raise ValueError(f"unknown calibration target type {type(target).__name__} "
                     "(use Chessboard, CharucoTarget or CalibrationObject)")


def _detect_object(gray, obj: CalibrationObject, name, size, min_corners) -> Detection:
    if not obj.faces or not all(isinstance(f, CharucoTarget) for f in obj.faces):
        raise ValueError("a calibration object needs ChArUco faces (with disjoint marker ids) to tell them apart")
    dicts = {f.dictionary for f in obj.faces}
    markers = {d: _aruco_markers(gray, d) for d in dicts}
    face_points = obj.object_points()
    objp, imgp, allids, offset = [], [], [], 0
    for face, pts in zip(obj.faces, face_points):
        ids, px = find_charuco(gray, face, markers[face.dictionary])
        objp.append(pts[ids])
        imgp.append(px)
        allids.append(ids + offset)
        offset += len(pts)
    ids = np.concatenate(allids)
    if len(ids) < min_corners:
        return Detection.failed(name, size, f"only {len(ids)} calibration-object corners found (need {min_corners})")
    return Detection(name, size, np.concatenate(objp), np.concatenate(imgp), ids)


def detect_targets(images: Sequence, target, names: Sequence[str] | None = None,
                   progress: Progress | None = None, min_corners: int = 6) -> list[Detection]:
    """:func:`detect_target` over many images (paths or arrays), in order.

    ``names`` default to the file names (``"#i"`` for arrays); ``progress(done, total, name)``
    is called after each image.
    """
    images = list(images)
    if names is None:
        names = [image_name(im, i) for i, im in enumerate(images)]
    elif len(names) != len(images):
        raise ValueError(f"got {len(names)} names for {len(images)} images")
    out = []
    for i, (im, nm) in enumerate(zip(images, names)):
        out.append(detect_target(im, target, nm, min_corners))
        if progress is not None:
            progress(i + 1, len(images), nm)
    return out
