"""Capture folders: the one on-disk form of a capture, shared by real and synthetic ones.

A capture folder holds (see ``docs/capture-folder.md``)::

    capture.json      what was captured and, per image, its file, camera and timing
    rig.json          the cameras (stillcap rig file, :meth:`stillcap.camera.Rig.save`)
    images/...        the photos (PNG or JPEG), OpenCV-readable
    truth.json        ground truth (synthetic captures only; content depends on ``kind``)

:meth:`Capture.load` validates everything a pipeline relies on: the files exist, every image's
camera is in the rig, paths stay inside the folder; :meth:`Capture.read_image` decodes an image
and checks its size against its camera. Every file is written atomically.

:func:`stereo_pairs` groups a capture's photos into strobed stereo pairs (:class:`StereoPairSpec`);
:func:`board_points_world` reads the calibration record a capture may hold (``meta.calibration``).
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stillcap.camera import Rig
from stillcap.files.atomic import atomic_path, write_text
from stillcap.files.images import check_image_file, read_image as _read_image_file
from stillcap.files.jsonfile import read_json
from stillcap.files.jsonable import to_jsonable
from stillcap.files.paths import resolve_inside, safe_relpath
from stillcap.io._capture_schema import (
    CAPTURE_FORMAT, CAPTURE_VERSION, KINDS, MAX_FLASHES, MAX_SECONDS, MAX_STROBE_HZ, TIMING as _TIMING, UNITS,
    check_capture_file, check_image_entry)

__all__ = ["capture_ball", "CAPTURE_FORMAT", "CAPTURE_VERSION", "KINDS", "MAX_FLASHES", "MAX_SECONDS", "MAX_STROBE_HZ", "UNITS",
           "CaptureImage", "Capture", "write_image", "target_to_dict", "target_from_dict", "board_points_world",
           "StereoPairSpec", "stereo_pairs"]
_RESERVED = {"format", "version", "kind", "units", "rig", "truth", "images"}


def _safe_relpath(file: str, where: str) -> str:
    """``file`` as a normalised relative POSIX path that cannot leave the capture folder."""
    return safe_relpath(file, where.rstrip(": ").strip(), "capture folder")


@dataclass
class CaptureImage:
    """One photo of a capture.

    Parameters
    ----------
    file : str
        Path relative to the capture folder (POSIX separators), e.g. ``"images/cam0.png"``.
    camera : str
        Name of the rig camera that took it.
    strobe_hz, shutter_s, first_flash_s : float, optional
        Multi-exposure timing: strobe rate (Hz), shutter open time (s), time of the first
        flash after the shutter opened (s).
    n_flashes : int, optional
        Number of flashes during the shutter.
    meta : dict
        Anything else per image (view index, turn angle in degrees, ...), JSON-serialisable.
    """

    file: str
    camera: str
    strobe_hz: float | None = None
    shutter_s: float | None = None
    first_flash_s: float | None = None
    n_flashes: int | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        # the checks of the Python API (files are checked by the capture schema first)
        self.file = _safe_relpath(self.file, "image ")
        if not isinstance(self.camera, str):
            raise ValueError(f"image {self.file!r}: camera must be a camera name (a string), got {self.camera!r}")
        for k, top in (("strobe_hz", MAX_STROBE_HZ), ("shutter_s", MAX_SECONDS), ("first_flash_s", MAX_SECONDS)):
            v = getattr(self, k)
            if v is not None:
                if not isinstance(v, numbers.Real) or isinstance(v, bool):
                    raise ValueError(f"image {self.file!r}: {k} must be a number, got {v!r}")
                v = float(v)
                if not math.isfinite(v) or v < 0 or (k == "strobe_hz" and v == 0) or v > top:
                    raise ValueError(f"image {self.file!r}: {k} must be a finite number "
                                     f"{'> 0' if k == 'strobe_hz' else '>= 0'} and <= {top:g}, got {v}")
                setattr(self, k, v)
        if self.n_flashes is not None:
            n = self.n_flashes
            if (not isinstance(n, numbers.Real) or isinstance(n, bool) or not math.isfinite(n) or int(n) != n
                    or not 0 <= n <= MAX_FLASHES):
                raise ValueError(f"image {self.file!r}: n_flashes must be a whole number from 0 to {MAX_FLASHES}, "
                                 f"got {n!r}")
            self.n_flashes = int(n)
        if not isinstance(self.meta, dict):
            raise ValueError(f"image {self.file!r}: meta must be a dict, got {self.meta!r}")

    @property
    def flash_times(self) -> np.ndarray | None:
        """Flash times in seconds from the shutter opening ``(n_flashes,)``, if the timing is known."""
        if self.strobe_hz is None or self.n_flashes is None:
            return None
        return (self.first_flash_s or 0.0) + np.arange(self.n_flashes) / self.strobe_hz

    def to_dict(self) -> dict:
        d = {"file": self.file, "camera": self.camera}
        d.update({k: getattr(self, k) for k in _TIMING if getattr(self, k) is not None})
        if self.meta:
            d["meta"] = to_jsonable(self.meta)
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "", *, prefix: tuple = ()) -> CaptureImage:
        """An image from its ``capture.json`` entry, checked by the capture schema: ``ValueError``
        ``WHERE: KEY.PATH: ...`` (``where``: the file, e.g. ``"capture.json: "``; ``prefix``: the
        entry's key path, e.g. ``("images", 3)``)."""
        source = where.strip().removesuffix(":").strip() or "capture"
        e = check_image_entry(d, source, prefix)
        try:
            file = safe_relpath(e.file, "", "capture folder")
            return cls(file, e.camera, e.strobe_hz, e.shutter_s, e.first_flash_s, e.n_flashes, dict(d.get("meta", {})))
        except ValueError as err:
            raise ValueError(f"{source}: {'.'.join(map(str, (*prefix, 'file')))}: {err}") from None


@dataclass
class Capture:
    """A capture: what was photographed, by which cameras, the photos and (if synthetic) the truth.

    Parameters
    ----------
    kind : str
        What was captured: ``"chessboard"``, ``"charuco"``, ``"calibration-object"``,
        ``"markers"``, ``"pitch"``, ``"hand"``, ``"puppet"``, ...
    rig : Rig
    images : list of CaptureImage
    truth : dict, optional
        Ground truth (synthetic captures), written to ``truth.json``.
    meta : dict
        Capture-wide description (e.g. ``"target"``: the calibration target, see
        :func:`target_to_dict`; ``"description"``; ``"synthetic"``).
    root : Path, optional
        The folder it was loaded from or saved to (image paths are relative to it).
    """

    kind: str
    rig: Rig
    images: list[CaptureImage] = field(default_factory=list)
    truth: dict | None = None
    meta: dict = field(default_factory=dict)
    root: Path | None = None
    # photos being decoded ahead (start_decoding): file -> Future of its read_image; shared by the
    # copies dataclasses.replace makes (a rig with other responses: the same photos)
    _decoding: dict = field(default_factory=dict, repr=False, compare=False, kw_only=True)

    def __post_init__(self):
        if not isinstance(self.kind, str) or not self.kind:
            raise ValueError(f"capture kind must be a non-empty string, got {self.kind!r}")
        self.images = list(self.images)
        if not isinstance(self.meta, dict):
            raise ValueError(f"capture meta must be a dict, got {self.meta!r}")
        clash = set(self.meta) & _RESERVED
        if clash:
            raise ValueError(f"capture meta must not use the reserved keys {sorted(clash)}")
        names = set(self.rig.names)
        seen = set()
        for im in self.images:
            if im.camera not in names:
                raise ValueError(f"image {im.file!r}: camera {im.camera!r} is not in the rig (cameras: {self.rig.names})")
            if im.file in seen:
                raise ValueError(f"image {im.file!r} is listed twice")
            seen.add(im.file)

    # --- access ---------------------------------------------------------------------------
    def images_of(self, camera: str) -> list[CaptureImage]:
        """The images taken by ``camera``, in file order of the capture."""
        if camera not in self.rig.names:
            raise ValueError(f"camera {camera!r} is not in the rig (cameras: {self.rig.names})")
        return [im for im in self.images if im.camera == camera]

    def path_of(self, image: CaptureImage | str | int) -> Path:
        """Absolute path of an image (by entry, file name or index)."""
        if self.root is None:
            raise ValueError("this capture has no folder yet (load or save it first)")
        im = self._entry(image)
        return self.root / im.file

    def _entry(self, image) -> CaptureImage:
        if isinstance(image, CaptureImage):
            return image
        if isinstance(image, (int, np.integer)):
            return self.images[int(image)]
        for im in self.images:
            if im.file == image:
                return im
        raise ValueError(f"no image {image!r} in the capture")

    def read_image(self, image: CaptureImage | str | int, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
        """Decode one image (BGR uint8 by default); ValueError naming the file if it cannot be
        decoded or its size differs from its camera's ``image_size``. A photo decoded ahead
        (:meth:`start_decoding`) is handed out once, to the first call in colour; later calls
        decode the file again, as without it."""
        im = self._entry(image)
        path = self.path_of(im)
        ahead = self._decoding.pop(im.file, None) if flags == cv2.IMREAD_COLOR else None
        # size and completeness checked before decoding (its errors come here from a decoding ahead)
        img = ahead.result() if ahead is not None else _read_image_file(path, flags)
        w, h = self.rig[im.camera].image_size
        if img.shape[:2] != (h, w):
            raise ValueError(f"image file {path} is {img.shape[1]}x{img.shape[0]} px but camera "
                             f"{im.camera!r} is {w}x{h} px")
        return img

    def start_decoding(self, images=None) -> None:
        """Start decoding photos (default: all) in colour on a background thread, for
        :meth:`read_image` to hand out: e.g. while the program still imports the pipeline that
        will read them (OpenCV's decoding releases the GIL, so it runs on another core). The
        photos and the errors are those :meth:`read_image` gives without it; a photo nobody
        reads stays in memory as long as the capture."""
        from concurrent.futures import ThreadPoolExecutor

        entries = [self._entry(im) for im in (self.images if images is None else images)]
        pool = ThreadPoolExecutor(1, thread_name_prefix="stillcap-decode")
        for im in entries:
            if im.file not in self._decoding:
                self._decoding[im.file] = pool.submit(_read_image_file, self.path_of(im), cv2.IMREAD_COLOR)
        pool.shutdown(wait=False)  # the thread ends after the last photo

    def __getstate__(self) -> dict:
        # a capture sent to a worker process goes without the photos decoded ahead here
        return {**self.__dict__, "_decoding": {}}

    def verify(self) -> None:
        """Decode every image (slow); raises ValueError naming the first bad file."""
        for im in self.images:
            self.read_image(im)

    # --- files ----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = {"format": CAPTURE_FORMAT, "version": CAPTURE_VERSION, "kind": self.kind, "units": dict(UNITS),
             "rig": "rig.json", "truth": "truth.json" if self.truth is not None else None}
        d.update(to_jsonable(self.meta))
        d["images"] = [im.to_dict() for im in self.images]
        return d

    def save(self, path, images: dict | None = None, jpeg_quality: int = 95) -> Path:
        """Write the capture folder (atomically, file by file).

        Parameters
        ----------
        path : folder to write (created if needed).
        images : dict, optional
            ``{file: image array}`` to write as well (PNG or JPEG by extension, JPEG at
            ``jpeg_quality``); every listed image must exist in the folder afterwards.
        """
        root = Path(path)
        root.mkdir(parents=True, exist_ok=True)
        listed = {im.file for im in self.images}
        for file, img in (images or {}).items():
            file = _safe_relpath(file, "")
            if file not in listed:
                raise ValueError(f"image {file!r} is not listed in the capture's images")
            write_image(root / file, img, jpeg_quality)
        missing = [im.file for im in self.images if not (root / im.file).is_file()]
        if missing:
            raise ValueError(f"capture {root}: image files missing: {missing[:5]}{' ...' if len(missing) > 5 else ''}")
        self.rig.save(root / "rig.json")
        if self.truth is not None:
            write_text(root / "truth.json", json.dumps(to_jsonable(self.truth), indent=1, allow_nan=False) + "\n")
        write_text(root / "capture.json", json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n")
        self.root = root
        return root

    @classmethod
    def load(cls, path, *, truth: bool = True) -> Capture:
        """Read and validate a capture folder (``path`` is the folder or its ``capture.json``).

        ``capture.json`` is checked by its schema (:class:`~stillcap.io._capture_schema.CaptureFile`,
        :class:`~stillcap.io._capture_schema.ImageEntry`), the rig by the rig schema, then: each
        image's camera is in the rig and its file stays inside the folder, exists, and is an image
        whose header gives its camera's size (checked, not decoded: :mod:`stillcap.files.images`),
        the ``pairs`` name cameras of the rig, and ``truth.json`` is an object. ``ValueError``
        naming the file and the key path otherwise. ``truth=False`` leaves ``truth.json`` unread
        (its path is still checked; the capture's ``truth`` is None): a pipeline never uses it,
        and the studio's puppet captures' 26 KB cost ~0.6 ms to parse.
        """
        root = Path(path)
        if root.name == "capture.json":
            root = root.parent
        cfile = root / "capture.json"
        if not root.is_dir():
            raise ValueError(f"capture folder {root} does not exist")
        if not cfile.is_file():
            raise ValueError(f"{cfile} does not exist: {root} is not a capture folder")
        d = read_json(cfile)
        c = check_capture_file(d, str(cfile))
        real_root = root.resolve()
        rig_file = resolve_inside(root, c.rig, f"{cfile}: rig", "capture folder", real_root=real_root)
        if not rig_file.is_file():
            raise ValueError(f"{cfile}: rig: rig file {rig_file} does not exist")
        rig = Rig.load(rig_file)
        images = [CaptureImage.from_dict(e, f"{cfile}: ", prefix=("images", i)) for i, e in enumerate(c.images)]
        seen: dict[str, int] = {}
        real_dirs: dict = {}  # the photos' folders, resolved once
        for i, im in enumerate(images):
            if im.camera not in rig.names:
                raise ValueError(f"{cfile}: images.{i}.camera: camera {im.camera!r} is not in the rig "
                                 f"{rig_file.name} (cameras: {rig.names})")
            if im.file in seen:
                raise ValueError(f"{cfile}: images.{i}.file: image {im.file!r} is listed twice (also images.{seen[im.file]})")
            seen[im.file] = i
            p = resolve_inside(root, im.file, f"{cfile}: images.{i}.file", "capture folder", real_root=real_root,
                               real_dirs=real_dirs)
            if not p.is_file():
                raise ValueError(f"{cfile}: images.{i}.file: image file {p} does not exist")
            header = check_image_file(p)
            w, h = rig[im.camera].image_size
            if (header.width, header.height) not in ((w, h), (h, w)):  # (h, w): an EXIF turn, read_image decides
                raise ValueError(f"image file {p} is {header.width}x{header.height} px but camera {im.camera!r} "
                                 f"is {w}x{h} px")
        in_pair: dict[str, str] = {}
        for name, cams in (c.pairs or {}).items():
            for j, cam in enumerate(cams):
                if cam not in rig.names:
                    raise ValueError(f"{cfile}: pairs.{name}.{j}: camera {cam!r} is not in the rig {rig_file.name} "
                                     f"(cameras: {rig.names})")
                if cam in in_pair:
                    raise ValueError(f"{cfile}: pairs.{name}.{j}: camera {cam!r} is already in the pair "
                                     f"{in_pair[cam]!r} (a camera belongs to one stereo pair)")
                in_pair[cam] = name
        truth_dict = None
        if c.truth is not None:
            tfile = resolve_inside(root, c.truth, f"{cfile}: truth", "capture folder", real_root=real_root)
            if not tfile.is_file():
                raise ValueError(f"{cfile}: truth: truth file {tfile} does not exist")
            if truth:
                truth_dict = read_json(tfile)
                if not isinstance(truth_dict, dict):
                    raise ValueError(f"{tfile}: (the whole file): a truth file must be an object, "
                                     f"got a JSON {type(truth_dict).__name__}")
        meta = {k: v for k, v in d.items() if k not in _RESERVED}
        try:
            return cls(c.kind, rig, images, truth_dict, meta, root)
        except ValueError as e:
            raise ValueError(f"{cfile}: {e}") from None


def capture_ball(capture: Capture):
    """The ball ``capture.json``'s ``ball`` key names (``docs/capture-folder.md``): a built-in
    ball's name, a ball file's path inside the capture folder (kept inside it), or a ball file's
    content; None without the key. ``ValueError`` naming ``capture.json``, the key and the
    problem otherwise."""
    spec = capture.meta.get("ball")
    if spec is None:
        return None
    from stillcap.ball.ballfile import resolve_ball
    where = f"{capture.root / 'capture.json'}: ball" if capture.root is not None else "capture.json: ball"
    return resolve_ball(spec, capture.root, where)


def write_image(path, image: np.ndarray, jpeg_quality: int = 95) -> Path:
    """Write an image atomically as PNG or JPEG (by the extension of ``path``)."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"image {path}: use a .png, .jpg or .jpeg file name")
    params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if ext != ".png" else []
    ok, buf = cv2.imencode(ext, np.asarray(image), params)
    if not ok:
        raise ValueError(f"image {path}: OpenCV could not encode an array of shape {np.shape(image)}")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
    return path


# --- calibration targets in capture.json ---------------------------------------------------
def target_to_dict(target) -> dict:
    """A calibration target as capture metadata (lengths in metres)."""
    from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard

    if isinstance(target, Chessboard):
        return {"type": "chessboard", "cols": target.cols, "rows": target.rows, "square": target.square,
                "margin": target.margin}
    if isinstance(target, CharucoTarget):
        return {"type": "charuco", "squares_x": target.squares_x, "squares_y": target.squares_y,
                "square": target.square, "marker": target.marker, "dictionary": int(target.dictionary),
                "first_id": target.first_id, "margin": target.margin}
    if isinstance(target, CalibrationObject):
        return {"type": "calibration-object", "faces": [target_to_dict(f) for f in target.faces],
                "face2object": [np.asarray(T, float).tolist() for T in target.face2object]}
    raise ValueError(f"unknown calibration target type {type(target).__name__}")


def target_from_dict(d: dict):
    """Inverse of :func:`target_to_dict`."""
    from stillcap.calibrate.targets import CalibrationObject, CharucoTarget, Chessboard

    kind = d.get("type") if isinstance(d, dict) else None
    args = {k: v for k, v in (d or {}).items() if k != "type"}
    try:
        if kind == "chessboard":
            return Chessboard(**args)
        if kind == "charuco":
            return CharucoTarget(**args)
        if kind == "calibration-object":
            return CalibrationObject(tuple(target_from_dict(f) for f in d["faces"]),
                                     tuple(np.asarray(T, float) for T in d["face2object"]))
    except (TypeError, KeyError) as e:
        raise ValueError(f"bad {kind} target description: {e}") from None
    raise ValueError(f"unknown calibration target type {kind!r} (chessboard, charuco, calibration-object)")


# --- calibration record in capture.json --------------------------------------------------
def board_points_world(calib: dict, pair_name: str, camera: str):
    """World coordinates of the calibration board corners a camera's pose was solved on (from
    the capture's ``meta.calibration`` record), or None when the record does not say."""
    try:
        target = target_from_dict(calib["extrinsics_target"])
        T = np.asarray(calib["board2world"][pair_name], float).reshape(-1, 4, 4)
        spots = calib["cameras"][camera].get("spots_used", range(len(T)))
        obj = target.object_points
        obj = np.asarray(obj() if callable(obj) else obj, float).reshape(-1, 3)
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    pts = [obj @ T[k][:3, :3].T + T[k][:3, 3] for k in spots if 0 <= int(k) < len(T)]
    return np.concatenate(pts) if pts else None


# --- strobed stereo pairs -----------------------------------------------------------------
@dataclass
class StereoPairSpec:
    """Two photos of one strobed stereo pair."""

    name: str
    images: tuple  # (CaptureImage, CaptureImage)
    strobe_hz: float

    @property
    def cameras(self) -> tuple:
        return tuple(im.camera for im in self.images)


def stereo_pairs(capture: Capture) -> tuple[list[StereoPairSpec], list[str]]:
    """Group a capture's photos into strobed stereo pairs.

    A photo's pair is ``images[].meta.pair``, else the pair of the capture's ``pairs`` map
    (``{"front": ["front_top", "front_bottom"], ...}``) holding its camera, else photos are
    grouped by strobe rate and paired in the order given. A group that is not exactly two photos
    of two cameras at one strobe rate is skipped with a message.

    Returns
    -------
    pairs : list of StereoPairSpec
        In the capture's order.
    messages : list of str

    Raises
    ------
    ValueError
        When no complete pair is left.
    """
    messages: list[str] = []
    cmap = capture.meta.get("pairs") if isinstance(capture.meta.get("pairs"), dict) else {}
    cam_pair = {str(c): str(name) for name, cams in cmap.items() for c in (cams or [])}
    groups: dict[str, list[CaptureImage]] = {}
    unnamed: list[CaptureImage] = []
    for im in capture.images:
        name = im.meta.get("pair") if isinstance(im.meta, dict) else None
        name = name if name is not None else cam_pair.get(im.camera)
        if name is None:
            unnamed.append(im)
        else:
            groups.setdefault(str(name), []).append(im)
    # photos without a pair name: by strobe rate, two by two in the order given
    by_rate: dict = {}
    for im in unnamed:
        by_rate.setdefault(None if im.strobe_hz is None else round(im.strobe_hz, 6), []).append(im)
    for rate, ims in by_rate.items():
        for i in range(0, len(ims), 2):
            groups.setdefault(f"pair{len(groups)}", []).extend(ims[i:i + 2])
    for name, cams in cmap.items():
        if name not in groups:
            messages.append(f"pair {name!r}: no photo in the capture (cameras {list(cams or [])}): skipped")
    out = []
    for name, ims in groups.items():
        files = ", ".join(im.file for im in ims)
        if len(ims) != 2:
            want = cmap.get(name)
            have = {im.camera for im in ims}
            missing = [c for c in (want or []) if c not in have]
            why = f"camera {', '.join(missing)} has no photo" if missing else f"{len(ims)} photo(s) ({files})"
            messages.append(f"pair {name!r}: {why}; a stereo pair needs one photo from each of two cameras: skipped")
            continue
        if ims[0].camera == ims[1].camera:
            messages.append(f"pair {name!r}: both photos are from camera {ims[0].camera!r}: skipped")
            continue
        rates = [im.strobe_hz for im in ims]
        if any(r is None for r in rates):
            messages.append(f"pair {name!r}: no strobe_hz for {files} (flash times unknown): skipped")
            continue
        if abs(rates[0] - rates[1]) > 1e-6 * max(rates):
            messages.append(f"pair {name!r}: the two photos have different strobe rates {rates} Hz: skipped")
            continue
        out.append(StereoPairSpec(name, (ims[0], ims[1]), float(rates[0])))
    if not out:
        detail = "; ".join(messages) if messages else "no photos"
        raise ValueError(f"capture {capture.root or ''}: no complete stereo pair ({detail})")
    return out, messages
