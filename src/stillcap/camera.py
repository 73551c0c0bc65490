"""Cameras and rigs.

A :class:`Camera` is OpenCV's pinhole model with radial (k1, k2, k3) and tangential (p1, p2)
distortion (Heikkila & Silven) plus a pose ``world2cam`` (4x4, world -> camera frame; camera
frame x right, y down, z forward). Pixels are ``(x, y)`` with the origin at the centre of the
top-left pixel, as in OpenCV. Units are SI (metres) unless a name says otherwise.

A :class:`Rig` is an ordered list of named cameras (order is kept as given: never sorted, so
"cam_10" does not jump ahead of "cam_2"). Rigs are saved as a documented JSON file
(``docs/rig-format.md``) and can be imported from OpenCV ``cv2.FileStorage`` YAML/XML files.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import cv2
import numpy as np
from pydantic import AfterValidator, BeforeValidator, Field, StrictInt, StrictStr, field_validator
from pydantic_core import PydanticCustomError

from stillcap._checks import as_array, as_points, is_rotation
from stillcap.files.atomic import write_text
from stillcap.files.jsonfile import read_json
from stillcap.files.schema import Finite, Model, describe, validate
from stillcap.response import Response

RIG_FORMAT = "stillcap-rig"
RIG_VERSION = 1
#: Limits of the rig file's numbers (``docs/rig-format.md``).
MAX_IMAGE_SIDE = 100_000  # pixels
MAX_PIXEL_VALUE = 1e6  # |entries of K| (focal lengths, principal point, skew), pixels
MAX_DISTORTION = 1e3  # |distortion coefficients|
MAX_TRANSLATION = 1e9  # |world2cam translation|, in the file's units
ROTATION_TOLERANCE = 1e-6  # |R R^T - I| (as Camera checks)


def pose_matrix(R, t) -> np.ndarray:
    """4x4 homogeneous transform from a 3x3 rotation and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = as_array(R, (3, 3), "R")
    T[:3, 3] = as_array(np.ravel(t), (3,), "t")
    return T


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``world2cam`` of a camera at ``eye`` looking at ``target`` with ``up`` pointing up in the image.

    Camera frame: z forward (towards ``target``), x right, y down.
    """
    eye = as_array(eye, (3,), "eye")
    z = as_array(target, (3,), "target") - eye
    if np.linalg.norm(z) == 0:
        raise ValueError("look_at: eye and target are the same point")
    z = z / np.linalg.norm(z)
    x = np.cross(z, as_array(up, (3,), "up"))  # right = forward x up
    if np.linalg.norm(x) < 1e-12:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    return pose_matrix(R, -R @ eye)


@dataclass
class Camera:
    """One calibrated camera.

    Parameters
    ----------
    name : str
    K : array_like, shape (3, 3)
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
    dist : array_like, shape (5,)
        OpenCV distortion ``(k1, k2, p1, p2, k3)``.
    world2cam : array_like, shape (4, 4)
        Rigid transform from world to camera coordinates.
    image_size : (width, height) in pixels.
    response : Response, str or dict
        How the camera's 8-bit values relate to radiance (:class:`stillcap.response.Response`;
        also its rig-file forms ``"srgb"``, ``"linear"``, ``{"gamma": g}``, ``{"lut": [...]}``).
        Default sRGB.
    """

    name: str
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    world2cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    image_size: tuple[int, int] = (640, 480)
    response: Response = field(default_factory=Response.srgb)

    def __post_init__(self):
        self.K = as_array(self.K, (3, 3), f"camera {self.name!r} K").copy()
        d = np.ravel(np.asarray(self.dist, float))
        if d.size > 5:
            if np.any(d[5:] != 0):
                raise ValueError(
                    f"camera {self.name!r}: only the 5-parameter distortion (k1, k2, p1, p2, k3) "
                    f"is supported, got {d.size} non-zero-padded coefficients"
                )
            d = d[:5]
        self.dist = np.zeros(5)  # padded with zeros (np.pad, ~3x slower, is ~10 % of a rig file's loading)
        self.dist[:d.size] = d
        self.world2cam = as_array(self.world2cam, (4, 4), f"camera {self.name!r} world2cam").copy()
        R = self.world2cam[:3, :3]
        if not is_rotation(R, 1e-6):
            raise ValueError(f"camera {self.name!r}: world2cam rotation is not a proper rotation")
        try:
            w, h = (int(v) for v in self.image_size)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"camera {self.name!r}: image_size must be two whole numbers (width, height), "
                             f"got {self.image_size!r}") from None
        if w <= 0 or h <= 0:
            raise ValueError(f"camera {self.name!r}: image_size must be positive, got {self.image_size}")
        self.image_size = (w, h)
        self.response = Response.from_json(self.response, f"camera {self.name!r}: response")

    # --- derived quantities -------------------------------------------------------------
    @classmethod
    def from_intrinsics(cls, name, fx, fy, cx, cy, image_size, dist=None, world2cam=None,
                        response: Response | None = None) -> Camera:
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(name, K, np.zeros(5) if dist is None else dist,
                   np.eye(4) if world2cam is None else world2cam, image_size,
                   Response.srgb() if response is None else response)

    @property
    def R(self) -> np.ndarray:
        """World -> camera rotation (3, 3)."""
        return self.world2cam[:3, :3]

    @property
    def t(self) -> np.ndarray:
        """World -> camera translation (3,)."""
        return self.world2cam[:3, 3]

    @property
    def cam2world(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = -self.R.T @ self.t
        return T

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        return -self.R.T @ self.t

    @property
    def P(self) -> np.ndarray:
        """3x4 projection matrix ``K [R | t]`` (for undistorted pixels)."""
        return self.K @ self.world2cam[:3]

    def with_pose(self, world2cam) -> Camera:
        return Camera(self.name, self.K, self.dist, world2cam, self.image_size, self.response)

    def with_response(self, response) -> Camera:
        """The same camera with another response (a :class:`Response` or its rig-file form)."""
        return Camera(self.name, self.K, self.dist, self.world2cam, self.image_size, response)

    # --- projection ---------------------------------------------------------------------
    def world_to_cam(self, points_world) -> np.ndarray:
        p, one = as_points(points_world, 3, "points_world")
        out = p @ self.R.T + self.t
        return out[0] if one else out

    def project(self, points_world, distort: bool = True) -> np.ndarray:
        """Pixels ``(N, 2)`` of world points ``(N, 3)``.

        NaN in, NaN out; points on or behind the camera plane (z <= 0) give NaN.
        Written in NumPy rather than ``cv2.projectPoints`` because it must pass NaN through and
        runs vectorised over millions of points; ``tests/test_camera.py`` checks both agree.
        """
        p, one = as_points(points_world, 3, "points_world")
        pc = p @ self.R.T + self.t
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(pc[:, 2] > 1e-12, pc[:, 2], np.nan)
            xn = pc[:, :2] / z[:, None]
        if distort and self.radially_distorted:
            # Beyond the radius where r * (1 + k1 r^2 + k2 r^4 + k3 r^6) stops growing, the
            # polynomial folds far-off points back into the image: they have no valid pixel.
            with np.errstate(invalid="ignore"):
                xn[np.sum(xn * xn, axis=1) > self.max_distortion_r2] = np.nan
        px = self.normalized_to_pixels(xn, distort=distort)
        return px[0] if one else px

    @property
    def distorted(self) -> bool:
        """Whether any distortion coefficient is non-zero (NaN counts), as ``np.any(self.dist)``:
        from Python floats, ~1/15 of its cost (asked per camera at every projection and
        triangulation, a few hundred times per puppet capture)."""
        return any(self.dist.tolist())

    @property
    def radially_distorted(self) -> bool:
        """Whether k1, k2 or k3 is non-zero (NaN counts), as ``np.any(self.dist[[0, 1, 4]])``."""
        k1, k2, _, _, k3 = self.dist.tolist()
        return bool(k1 or k2 or k3)

    @property
    def max_distortion_r2(self) -> float:
        """Squared normalised radius up to which the radial distortion is monotonic (inf if always).

        The derivative of ``r * (1 + k1 r^2 + k2 r^4 + k3 r^6)`` is the cubic
        ``1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3`` in ``s = r^2``; its smallest positive root is the limit.
        Kept for the coefficients it was found for (``dist`` may be changed in place).
        """
        k1, k2, _, _, k3 = self.dist
        key = (float(k1), float(k2), float(k3))
        cached = self.__dict__.get("_max_r2")
        if cached is not None and cached[0] == key:
            return cached[1]
        roots = np.roots([7 * k3, 5 * k2, 3 * k1, 1.0]) if (k1 or k2 or k3) else np.array([])
        real = roots[np.abs(roots.imag) < 1e-12].real
        real = real[real > 0]
        r2 = float(real.min()) if len(real) else np.inf
        self.__dict__["_max_r2"] = (key, r2)
        return r2

    def distort_normalized(self, xn) -> np.ndarray:
        """Apply the lens distortion to normalised image coordinates ``(N, 2)``."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xn[:, 0], xn[:, 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    def normalized_to_pixels(self, xn, distort: bool = True) -> np.ndarray:
        xn = as_array(xn, (None, 2), "normalized points")
        if distort and self.distorted:
            xn = self.distort_normalized(xn)
        K = self.K
        u = K[0, 0] * xn[:, 0] + K[0, 1] * xn[:, 1] + K[0, 2]
        v = K[1, 1] * xn[:, 1] + K[1, 2]
        return np.stack([u, v], axis=1)

    def pixels_to_normalized(self, pixels) -> np.ndarray:
        """Undistorted normalised coordinates ``(N, 2)`` of distorted pixels ``(N, 2)``; NaN kept.

        Uses OpenCV's iterative undistortion with a tight stopping rule (the default 5 iterations
        leave errors of 0.1 px and more at the corners of strongly distorted lenses).
        """
        px, one = as_points(pixels, 2, "pixels")
        if not self.distorted:
            K = self.K  # pinhole: closed form, NaN propagates by itself
            y = (px[:, 1] - K[1, 2]) / K[1, 1]
            out = np.stack([(px[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y], axis=1)
            return out[0] if one else out
        out = np.full(px.shape, np.nan)
        ok = np.isfinite(px[:, 0]) & np.isfinite(px[:, 1])
        if np.any(ok):
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
            und = cv2.undistortPoints(px[ok].reshape(-1, 1, 2), self.K, self.dist, None, None, None, crit)
            out[ok] = und.reshape(-1, 2)
        return out[0] if one else out

    def undistort_points(self, pixels) -> np.ndarray:
        """Distorted pixels -> ideal (undistorted) pixels of the same camera, ``(N, 2)``."""
        px, one = as_points(pixels, 2, "pixels")
        out = self.normalized_to_pixels(self.pixels_to_normalized(px), distort=False)
        return out[0] if one else out

    def undistort_image(self, image: np.ndarray, interpolation=cv2.INTER_LINEAR) -> np.ndarray:
        """The image as an ideal pinhole camera with the same ``K`` would have taken it."""
        image = np.asarray(image)
        if image.shape[:2] != (self.image_size[1], self.image_size[0]):
            raise ValueError(
                f"camera {self.name!r}: image is {image.shape[1]}x{image.shape[0]} px, "
                f"the camera is {self.image_size[0]}x{self.image_size[1]} px"
            )
        if not self.distorted:
            return image.copy()
        m1, m2 = cv2.initUndistortRectifyMap(self.K, self.dist, None, self.K, self.image_size, cv2.CV_32FC1)
        return cv2.remap(image, m1, m2, interpolation)

    def rays(self, pixels) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to world rays: ``origins (N, 3)`` (the centre) and unit ``directions (N, 3)``."""
        px, one = as_points(pixels, 2, "pixels")
        xn = self.pixels_to_normalized(px)
        d_cam = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
        d = d_cam @ self.R  # R^T applied to each row
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        o = np.broadcast_to(self.center, d.shape).copy()
        return (o[0], d[0]) if one else (o, d)

    # --- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "image_size": list(self.image_size),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "world2cam": self.world2cam.tolist(),
            "response": self.response.to_json(),
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "", *, prefix: tuple = ()) -> Camera:
        """A camera from its rig-file entry (``docs/rig-format.md``), checked by the rig schema
        (:class:`RigFile`): ``ValueError`` ``WHERE: KEY.PATH: ... [camera 'NAME']``.

        ``where``: the file (and what holds the entry), e.g. ``"rig.json: "``; ``prefix``: the
        entry's key path inside it."""
        return _camera_entry(d, _source(where), prefix)


def _source(where: str) -> str:
    """``"rig.json: "`` (the prefix style of ``where`` arguments) as a message source ``"rig.json"``."""
    return where.strip().removesuffix(":").strip() or "rig"


class Rig:
    """Ordered, named cameras sharing one world frame."""

    def __init__(self, cameras, world: str = "world"):
        self.cameras: list[Camera] = list(cameras)
        self.world = world
        names = [c.name for c in self.cameras]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"rig has duplicate camera names: {sorted(dup)}")

    def __len__(self):
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras)

    def __getitem__(self, key) -> Camera:
        if isinstance(key, str):
            for c in self.cameras:
                if c.name == key:
                    return c
            raise KeyError(f"no camera named {key!r} in the rig (cameras: {self.names})")
        return self.cameras[key]

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def subset(self, names) -> Rig:
        return Rig([self[n] for n in names], self.world)

    def with_responses(self, responses) -> Rig:
        """The rig with other camera responses: one :class:`Response` for every camera, or a dict
        camera name -> Response (cameras not in it keep theirs)."""
        if isinstance(responses, dict):
            return Rig([c.with_response(responses[c.name]) if c.name in responses else c for c in self.cameras],
                       self.world)
        return Rig([c.with_response(responses) for c in self.cameras], self.world)

    def project(self, points_world) -> np.ndarray:
        """Pixels of world points in every camera, ``(n_cams, N, 2)``: :meth:`Camera.project`
        of each camera, the same numbers, the pinhole cameras' in one set of stacked array
        operations (each camera's ``p @ R.T`` is the same BLAS product in NumPy's stacked
        matmul; a loop over the cameras cost ~25 us per camera on a handful of points)."""
        p, _ = as_points(points_world, 3, "points_world")
        cams = self.cameras
        if not cams:
            return np.zeros((0, len(p), 2))
        w2c = np.stack([c.world2cam for c in cams])
        pc = p @ w2c[:, :3, :3].transpose(0, 2, 1) + w2c[:, None, :3, 3]  # (n_cams, N, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(pc[..., 2] > 1e-12, pc[..., 2], np.nan)
            x, y = pc[..., 0] / z, pc[..., 1] / z
        K = np.stack([c.K for c in cams])
        out = np.stack([K[:, 0, 0, None] * x + K[:, 0, 1, None] * y + K[:, 0, 2, None],
                        K[:, 1, 1, None] * y + K[:, 1, 2, None]], axis=-1)
        for v, c in enumerate(cams):
            if c.distorted:  # a lens with distortion: its own projection
                out[v] = c.project(p)
        return out

    # --- files --------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"format": RIG_FORMAT, "version": RIG_VERSION, "units": "m", "world": self.world,
                "cameras": [c.to_dict() for c in self.cameras]}

    def save(self, path) -> Path:
        """Write the rig as JSON (atomically)."""
        return write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def from_dict(cls, d: dict, where: str = "", *, prefix: tuple = ()) -> Rig:
        """A rig from the content of a rig file (``docs/rig-format.md``), checked by the rig schema
        (:class:`RigFile`): ``ValueError`` ``WHERE: KEY.PATH: ...`` for the first
        problem (``where``: the file, e.g. ``"rig.json: "``; ``prefix``: the rig's key path when it
        is embedded in another file)."""
        cams, world = _rig_cameras(d, _source(where), prefix)
        return cls(cams, world)

    @classmethod
    def load(cls, path) -> Rig:
        return cls.from_dict(read_json(path, "rig file"), f"{path}: ")

    @classmethod
    def from_opencv(cls, *paths, names=None, image_size=None, square_size: float = 1.0) -> Rig:
        """Import cameras from ``cv2.FileStorage`` files (YAML or XML).

        Understands the node names OpenCV's samples and tutorials write: a single camera as
        ``camera_matrix``/``cameraMatrix``/``K`` + ``distortion_coefficients``/``dist_coeffs``/``D``
        (+ ``image_width``/``image_height``), or a stereo pair as ``M1, D1, M2, D2`` with ``R, T``
        (possibly split over ``intrinsics.yml`` and ``extrinsics.yml``). The first camera is the
        world frame; ``T`` is multiplied by ``square_size`` to give metres.
        """
        nodes: dict[str, np.ndarray] = {}
        for p in paths:
            p = Path(p)
            if not p.exists():
                raise ValueError(f"OpenCV calibration file {p} does not exist")
            fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
            if not fs.isOpened():
                raise ValueError(f"{p} is not an OpenCV FileStorage file")
            root = fs.root()
            for key in root.keys():
                n = root.getNode(key)
                if n.isReal() or n.isInt():
                    nodes[key] = np.array(n.real())
                elif not n.isNone() and not n.isString():
                    m = n.mat()
                    if m is not None:
                        nodes[key] = np.asarray(m, float)
            fs.release()

        def pick(*keys):
            for k in keys:
                if k in nodes:
                    return nodes[k]
            return None

        size = image_size
        if size is None:
            w, h = pick("image_width", "imageWidth"), pick("image_height", "imageHeight")
            size = (int(w), int(h)) if w is not None and h is not None else None
            if size is None and (s := pick("image_size", "imageSize")) is not None:
                size = tuple(int(v) for v in np.ravel(s)[:2])
        if size is None:
            raise ValueError(f"{', '.join(map(str, paths))}: no image size found; pass image_size=(w, h)")
        if "M1" in nodes:
            if "M2" not in nodes:
                raise ValueError("stereo OpenCV file has M1 but no M2")
            names = names or ["left", "right"]
            c1 = Camera(names[0], nodes["M1"], np.ravel(nodes.get("D1", np.zeros(5))), np.eye(4), size)
            R, T = pick("R"), pick("T")
            if R is None or T is None:
                raise ValueError("stereo OpenCV files have intrinsics but no R and T (add extrinsics.yml)")
            c2 = Camera(names[1], nodes["M2"], np.ravel(nodes.get("D2", np.zeros(5))),
                        pose_matrix(R, np.ravel(T) * square_size), size)
            return cls([c1, c2])
        K = pick("camera_matrix", "cameraMatrix", "K", "intrinsic", "mtx")
        if K is None:
            raise ValueError(f"{', '.join(map(str, paths))}: no camera matrix (camera_matrix, cameraMatrix, K or M1)")
        D = pick("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist")
        name = (names or ["cam0"])[0]
        return cls([Camera(name, K, np.zeros(5) if D is None else np.ravel(D), np.eye(4), size)])


# --- the rig file's schema (docs/rig-format.md) -------------------------------------------
def _exactly(value: float, why: str):
    def check(v: float) -> float:
        if v != value:
            raise PydanticCustomError("exact", "must be {value} ({why})", {"value": value, "why": why})
        return v
    return AfterValidator(check)


_K_FORM = "K is [[fx, s, cx], [0, fy, cy], [0, 0, 1]]"
_Focal = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_PIXEL_VALUE)]
_Pixel = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_PIXEL_VALUE, le=MAX_PIXEL_VALUE)]
_Zero = Annotated[Finite, _exactly(0, _K_FORM)]
_One = Annotated[Finite, _exactly(1, _K_FORM)]
_Coefficient = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_DISTORTION, le=MAX_DISTORTION)]
_Side = Annotated[StrictInt, Field(ge=1, le=MAX_IMAGE_SIDE)]
_Entry = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=-MAX_TRANSLATION, le=MAX_TRANSLATION)]


def _rig_version(v: int) -> int:
    if not 1 <= v <= RIG_VERSION:
        raise PydanticCustomError("version", "must be a rig file version this stillcap reads ({versions})",
                                  {"versions": "1" if RIG_VERSION == 1 else f"1 to {RIG_VERSION}"})
    return v


def _response(value: Any) -> Response:
    try:
        return Response.from_json(value, "")
    except ValueError as e:
        # the schema's message adds "(got VALUE)" itself
        why = re.sub(r",? got .*$", "", str(e).removeprefix(": "))
        raise PydanticCustomError("response", "{why}", {"why": why}) from None


class CameraEntry(Model):
    """One camera of a rig file: ``name``, ``image_size``, ``K``, ``dist``, ``world2cam``,
    ``response`` (default ``"srgb"``: rigs written before the key existed read as sRGB)."""

    name: Annotated[StrictStr, Field(min_length=1)]
    image_size: tuple[_Side, _Side]
    K: tuple[tuple[_Focal, _Pixel, _Pixel], tuple[_Zero, _Focal, _Pixel], tuple[_Zero, _Zero, _One]]
    dist: Annotated[list[_Coefficient], Field(max_length=14)] = [0.0] * 5
    world2cam: Annotated[list[tuple[_Entry, _Entry, _Entry, _Entry]], Field(min_length=3, max_length=4)] = \
        [(1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0)]
    response: Annotated[Any, BeforeValidator(_response)] = Response.srgb()

    @field_validator("dist")
    @classmethod
    def _five_coefficients(cls, dist: list) -> list:
        extra = [i for i, k in enumerate(dist) if i >= 5 and k != 0]
        if extra:
            raise PydanticCustomError("distortion", "only the 5-parameter distortion (k1, k2, p1, p2, k3) is "
                                      "supported; coefficient {i} is {k}", {"i": extra[0], "k": dist[extra[0]]})
        return dist

    @field_validator("world2cam")
    @classmethod
    def _rigid(cls, rows: list) -> list:
        if len(rows) == 4 and tuple(rows[3]) != (0.0, 0.0, 0.0, 1.0):
            raise PydanticCustomError("rigid", "must be a rigid transform: its last row must be [0, 0, 0, 1]")
        R = np.array([r[:3] for r in rows[:3]])
        if not is_rotation(R, ROTATION_TOLERANCE):
            raise PydanticCustomError(  # (the template takes no format specs: the numbers come as text)
                "rigid", "must be a rigid transform: its rotation part (3x3) is not a proper rotation "
                "(R R^T differs from I by {err}, det(R) = {det})",
                {"err": f"{np.abs(R @ R.T - np.eye(3)).max():.2g}", "det": f"{np.linalg.det(R):.3g}"})
        return rows


class RigFile(Model):
    """A rig file's top level: ``format``, ``version``, ``units``, ``world``, ``cameras``."""

    format: Literal["stillcap-rig"]
    version: Annotated[StrictInt, AfterValidator(_rig_version)] = 1
    units: Literal["m", "cm", "mm"] = "m"
    world: StrictStr = "world"
    cameras: Annotated[list[dict[str, Any]], Field(min_length=1)]


_UNIT_SCALE = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}


def _camera_entry(d, source: str, prefix: tuple = (), scale: float = 1.0) -> Camera:
    """A camera from a rig-file entry ``d`` checked by :class:`CameraEntry` (``source``: the file,
    ``prefix``: the entry's key path); the message names the camera when the entry has a name."""
    name = d.get("name") if isinstance(d, dict) else None
    if isinstance(name, str) and name:
        source = f"{source}: camera {name!r}"
    e = validate(CameraEntry, d, source, prefix)
    rows = [list(r) for r in e.world2cam]
    world2cam = np.array(rows if len(rows) == 4 else rows + [[0.0, 0.0, 0.0, 1.0]])
    world2cam[:3, 3] *= scale
    try:
        return Camera(e.name, np.array(e.K), np.array(e.dist), world2cam, e.image_size, e.response)
    except ValueError as err:  # Camera's own checks (the schema should have said it first)
        raise ValueError(f"{source}: {'.'.join(map(str, prefix)) or '(the entry)'}: {err}") from None


def _rig_cameras(d, source: str, prefix: tuple = ()) -> tuple[list[Camera], str]:
    """The cameras and world-frame name of a rig file's content ``d``, checked by :class:`RigFile`
    and :class:`CameraEntry`; ``ValueError`` ``SOURCE: KEY.PATH: ...`` for the first problem."""
    if not isinstance(d, dict) or d.get("format") != RIG_FORMAT:
        got = describe(d.get("format")) if isinstance(d, dict) else f"a JSON {type(d).__name__}"
        path = ".".join(map(str, (*prefix, "format")))
        raise ValueError(f"{source}: {path}: not a stillcap rig file (expected \"format\": \"{RIG_FORMAT}\", "
                         f"got {got})")
    rig = validate(RigFile, d, source, prefix)
    scale = _UNIT_SCALE[rig.units]
    cams = [_camera_entry(cd, source, (*prefix, "cameras", i), scale) for i, cd in enumerate(rig.cameras)]
    first: dict[str, int] = {}
    for i, c in enumerate(cams):
        if c.name in first:
            path = ".".join(map(str, (*prefix, "cameras", i, "name")))
            raise ValueError(f"{source}: {path}: camera name {c.name!r} is used twice (also cameras.{first[c.name]}); "
                             "names must be unique")
        first[c.name] = i
    return cams, rig.world
