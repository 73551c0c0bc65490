"""Calibration targets: planar chessboards, ChArUco boards and 3D calibration objects.

One definition serves both sides: calibration detects a target in photos and needs its 3D points
(:meth:`object_points`), the synthetic studio renders it from its printed texture
(:meth:`texture`).

Board frame (OpenCV's): origin at the first inner corner (chessboard) or at the board's top-left
corner (ChArUco), x along the columns, y along the rows, z = 0 on the board, metres. A texture
covers the board-plane rectangle ``extent = (xmin, ymin, xmax, ymax)``: texture pixel ``(u, v)``
(pixel centres at integer coordinates) sits at
``x = xmin + (u + 0.5) / width * (xmax - xmin)``, ``y = ymin + (v + 0.5) / height * (ymax - ymin)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


#: Most inner corners (chessboard) or squares (ChArUco) along one side of a board: far more than
#: any printed board, few enough that a typo (``9x66666``) does not send the detector searching.
MAX_PER_SIDE = 100


def parse_pattern(text: str) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)`` (inner corners along x, along y)."""
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"pattern must look like 9x6 (inner corners), got {text!r}") from None
    if cols < 2 or rows < 2:
        raise ValueError(f"pattern needs at least 2x2 inner corners, got {text!r}")
    if cols > MAX_PER_SIDE or rows > MAX_PER_SIDE:
        raise ValueError(f"pattern has at most {MAX_PER_SIDE} inner corners per side, got {text!r}")
    return cols, rows


def _check_count(what: str, v, lo: int) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= MAX_PER_SIDE:
        raise ValueError(f"{what} must be a whole number from {lo} to {MAX_PER_SIDE}, got {v!r}")


def _check_length(what: str, v, hi: float = np.inf) -> None:
    try:
        ok = 0 < float(v) < hi
    except (TypeError, ValueError):
        ok = False
    if not ok:
        bound = f"between 0 and {hi:g}" if np.isfinite(hi) else "a positive finite length"
        raise ValueError(f"{what} must be {bound} (metres), got {v!r}")


@dataclass(frozen=True)
class Chessboard:
    """A chessboard with ``cols x rows`` inner corners and squares of ``square`` metres."""

    cols: int = 9
    rows: int = 6
    square: float = 0.025
    margin: float = 1.0  # white border, in squares, around the (cols+1) x (rows+1) squares

    def __post_init__(self):
        _check_count("chessboard inner corners along x (cols)", self.cols, 2)
        _check_count("chessboard inner corners along y (rows)", self.rows, 2)
        _check_length("chessboard square", self.square)

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> np.ndarray:
        """Inner corners ``(cols*rows, 3)`` in OpenCV's detection order (x fastest), z = 0."""
        j, i = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([j.ravel(), i.ravel(), np.zeros(j.size)], axis=1) * self.square

    @property
    def extent(self) -> tuple[float, float, float, float]:
        s, m = self.square, self.margin
        return (-(1 + m) * s, -(1 + m) * s, (self.cols + m) * s, (self.rows + m) * s)

    def texture(self, px_per_square: int = 64) -> np.ndarray:
        """The printed board, uint8 grey, covering :attr:`extent`."""
        m = int(round(self.margin * px_per_square))
        nx, ny = self.cols + 1, self.rows + 1
        sq = (np.add.outer(np.arange(ny), np.arange(nx)) % 2 == 0)  # top-left square black
        board = np.where(np.kron(sq, np.ones((px_per_square, px_per_square), bool)), 0, 255).astype(np.uint8)
        return np.pad(board, m, constant_values=255)


@dataclass(frozen=True)
class CharucoTarget:
    """A ChArUco board: ``squares_x x squares_y`` squares with ArUco markers in the white ones.

    ``first_id`` offsets the marker ids so that several boards (the faces of a calibration
    object) can be told apart in one photo.
    """

    squares_x: int = 7
    squares_y: int = 5
    square: float = 0.04
    marker: float = 0.03
    dictionary: int = cv2.aruco.DICT_5X5_250
    first_id: int = 0
    margin: float = 0.5  # white border, in squares

    def __post_init__(self):
        _check_count("ChArUco squares along x", self.squares_x, 2)
        _check_count("ChArUco squares along y", self.squares_y, 2)
        _check_length("ChArUco square", self.square)
        _check_length("ChArUco marker", self.marker, hi=float(self.square))
        try:
            size = cv2.aruco.getPredefinedDictionary(self.dictionary).bytesList.shape[0]
        except (cv2.error, TypeError, OverflowError):
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}") from None
        n = (self.squares_x * self.squares_y) // 2
        if self.first_id < 0 or self.first_id + n > size:
            raise ValueError(f"a {self.squares_x}x{self.squares_y} ChArUco board needs {n} markers from id "
                             f"{self.first_id}, but its dictionary holds {size}")

    def board(self) -> cv2.aruco.CharucoBoard:
        n = (self.squares_x * self.squares_y) // 2
        d = cv2.aruco.getPredefinedDictionary(self.dictionary)
        ids = np.arange(self.first_id, self.first_id + n, dtype=np.int32)
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, d, ids)

    def object_points(self) -> np.ndarray:
        """Chessboard corners ``(n_corners, 3)`` indexed by ChArUco corner id, z = 0."""
        return np.asarray(self.board().getChessboardCorners(), float).reshape(-1, 3)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        s, m = self.square, self.margin
        return (-m * s, -m * s, (self.squares_x + m) * s, (self.squares_y + m) * s)

    def texture(self, px_per_square: int = 64) -> np.ndarray:
        w, h = self.squares_x * px_per_square, self.squares_y * px_per_square
        img = self.board().generateImage((w, h), marginSize=0, borderBits=1)
        return np.pad(img, int(round(self.margin * px_per_square)), constant_values=255)


@dataclass(frozen=True)
class CalibrationObject:
    """A rigid 3D calibration object: planar targets on its faces.

    ``faces[i]`` is a target and ``face2object[i]`` (4x4) places that board's frame in the
    object's frame. ChArUco faces must use disjoint marker ids (``first_id``) so that a photo
    tells the faces apart.
    """

    faces: tuple = ()
    face2object: tuple = ()

    @classmethod
    def charuco_box(cls, square: float = 0.04, squares: tuple[int, int] = (5, 5)) -> CalibrationObject:
        """Three ChArUco boards on three mutually orthogonal planes meeting in a corner.

        The object frame has its origin at the shared corner; face 0 covers ``z = 0, x, y >= 0``,
        face 1 ``x = 0, y, z >= 0`` and face 2 ``y = 0, z, x >= 0`` (an inside corner, seen
        whole from directions with positive x, y and z).
        """
        nx, ny = squares
        per = (nx * ny) // 2
        faces, poses = [], []
        # Columns: where the board's x, y and z axes go. The board z axis points into the
        # object (away from the viewer), as for a board on a wall seen from the front;
        # otherwise the printed faces would read mirror-imaged and ArUco would find nothing.
        rots = [np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]]),   # z = 0 face: x->y, y->x
                np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]),   # x = 0 face: x->z, y->y
                np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])]   # y = 0 face: x->x, y->z
        for k, R in enumerate(rots):
            faces.append(CharucoTarget(nx, ny, square, 0.75 * square, first_id=k * per, margin=0.0))
            T = np.eye(4)
            T[:3, :3] = R
            poses.append(T)
        return cls(tuple(faces), tuple(poses))

    def object_points(self) -> list[np.ndarray]:
        """Per face: its corners in the object frame ``(n_i, 3)``."""
        out = []
        for f, T in zip(self.faces, self.face2object):
            p = f.object_points()
            out.append(p @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3])
        return out
