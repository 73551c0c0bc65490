"""The puppet project (SPEC J3 "Files"), :class:`Project`: photos, their turn angles or cameras,
identified markers.

A project is a folder::

    my_puppet/
      project.json      format, rig or turntable, marker set, views (see docs/project-format.md)
      photos/           the photos (and processed photos), one per view

Per view it stores the photo, the turn angle in degrees (turntable) or the camera name (rig),
the markers the detector found (``detected``) and, separately, the user's manual edits
(``edits``: delete, relabel, move/add). The markers a view contributes are the automatic
detections with the edits applied in order, so re-running detection (:meth:`Project.set_detections`)
keeps what the user corrected. 3D markers are never stored: :meth:`Project.reconstruct`
recomputes them (as the thesis's program did on load).

Every path in ``project.json`` is relative to the project folder and must stay inside it
(absolute paths, ``..`` and symlinks leading out are refused). Every file is written atomically
(temporary file + rename): an error never leaves a half-written project.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import cv2
import numpy as np

from stillcap.body.markerset import MarkerSet
from stillcap.body.skeleton import Skeleton
from stillcap.camera import RIG_FORMAT, Camera, Rig
from stillcap.geometry.triangulate import triangulate
from stillcap.files.atomic import write_bytes, write_text
from stillcap.files.images import check_image_file, decode_image, read_image
from stillcap.files.jsonfile import read_json
from stillcap.files.paths import resolve_inside, safe_relpath
from stillcap.files.schema import MAX_COORDINATE, validate
from stillcap.io.project._records import (BUILTIN_MARKERSETS, IMAGE_SUFFIXES, PHOTOS_DIR, PROJECT_FILE, PROJECT_FORMAT,
                                          PROJECT_VERSION, UNITS, Edit, Markers3D, ProjectFile, TurntableSetup, View,
                                          _check_xy, _file_stem, _format_angle, _same_angle, _view_from_entry,
                                          dumps_json)


# --- the project --------------------------------------------------------------------------
@dataclass(eq=False)
class Project:
    """A puppet project folder (see the module docstring and ``docs/project-format.md``).

    Make one with :meth:`create`, open one with :meth:`load`. Exactly one of ``turntable`` and
    ``rig`` is set.

    Parameters
    ----------
    root : Path
        The project folder.
    markerset : MarkerSet
    turntable : TurntableSetup, optional
        Turntable projects: views carry ``angle_deg``.
    rig : Rig, optional
        Multi-camera projects: views carry ``camera``.
    views : list of View
    name : str
    rig_file : str, optional
        If set, the rig lives in this file (relative to ``root``) instead of inside project.json.
    meta : dict
        Free JSON-serialisable notes.
    skeleton : Skeleton, optional
        The puppet's skeleton (key ``skeleton``: a built-in name, ``{"file": PATH}`` inside the
        folder, or the file embedded); None: the built-in puppet.
    """

    root: Path
    markerset: MarkerSet
    turntable: TurntableSetup | None = None
    rig: Rig | None = None
    views: list[View] = field(default_factory=list)
    name: str = ""
    rig_file: str | None = None
    meta: dict = field(default_factory=dict)
    _stale_files: set = field(default_factory=set, repr=False)
    skeleton: Skeleton | None = None
    _skeleton_file: dict | None = field(default=None, repr=False)

    def __post_init__(self):
        self.root = Path(self.root)
        if (self.turntable is None) == (self.rig is None):
            raise ValueError("a project needs exactly one of turntable= and rig=")
        if not isinstance(self.markerset, MarkerSet):
            raise ValueError(f"markerset must be a MarkerSet, got {type(self.markerset).__name__}")
        if self.skeleton is not None and not isinstance(self.skeleton, Skeleton):
            raise ValueError(f"skeleton must be a Skeleton or None, got {type(self.skeleton).__name__}")
        if self.rig_file is not None:
            self.rig_file = safe_relpath(self.rig_file, "rig file")
        self.views = list(self.views)

    # --- construction ---------------------------------------------------------------------
    @classmethod
    def create(cls, folder, *, turntable: TurntableSetup | None = None, rig: Rig | None = None,
               markerset: MarkerSet | str = "puppet-16", name: str | None = None,
               rig_file: str | None = None, save: bool = True, skeleton: Skeleton | None = None) -> Project:
        """A new, empty project in ``folder`` (created if needed).

        Parameters
        ----------
        folder : path
            Must not already hold a ``project.json``.
        turntable : TurntableSetup, optional
            A turntable project (default when ``rig`` is not given: the thesis's setup).
        rig : Rig, optional
            A multi-camera project.
        markerset : MarkerSet or str
            A MarkerSet or the name of a built-in one (``"puppet-16"``).
        rig_file : str, optional
            Keep the rig in this file (relative to the folder, written now) instead of inside
            project.json.
        save : bool
            Write project.json now (importers pass False and save once at the end).
        skeleton : Skeleton, optional
            The puppet's own skeleton (kept in project.json; default the built-in puppet's).
        """
        root = Path(folder)
        if (root / PROJECT_FILE).exists():
            raise ValueError(f"{root} already holds a project ({PROJECT_FILE}); load it or choose another folder")
        if root.exists() and not root.is_dir():
            raise ValueError(f"project folder {root} exists and is not a folder")
        if rig is None and turntable is None:
            turntable = TurntableSetup()
        if rig_file is not None and rig is None:
            raise ValueError("rig_file= needs a rig=")
        if isinstance(markerset, str):
            if markerset not in BUILTIN_MARKERSETS:
                raise ValueError(f"unknown marker set {markerset!r}; built-in: {sorted(BUILTIN_MARKERSETS)}")
            markerset = BUILTIN_MARKERSETS[markerset]()
        markerset.check_skeleton(skeleton or Skeleton.puppet())
        project = cls(root, markerset, turntable, rig, [], name if name is not None else root.name,
                      rig_file, {}, skeleton=skeleton)
        root.mkdir(parents=True, exist_ok=True)
        if rig_file is not None:
            rig.save(resolve_inside(root, rig_file, "rig file"))
        if save:
            project.save()
        return project

    @property
    def is_turntable(self) -> bool:
        return self.turntable is not None

    @property
    def path(self) -> Path:
        """The project file, ``root / "project.json"``."""
        return self.root / PROJECT_FILE

    # --- views ----------------------------------------------------------------------------
    def view(self, key) -> View:
        """A view by :class:`View`, index (int) or name (str)."""
        if isinstance(key, View):
            if not any(v is key for v in self.views):
                raise ValueError(f"view {key.name!r} is not in this project")
            return key
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if not -len(self.views) <= int(key) < len(self.views):
                raise ValueError(f"view index {key} is out of range (the project has {len(self.views)} views)")
            return self.views[int(key)]
        if isinstance(key, str):
            for v in self.views:
                if v.name == key:
                    return v
            raise ValueError(f"no view named {key!r} in the project (views: {[v.name for v in self.views]})")
        raise ValueError(f"a view is addressed by index or name, got {key!r}")

    def view_at(self, angle_deg: float) -> View | None:
        """The view taken at turn angle ``angle_deg`` (modulo 360), or None."""
        for v in self.views:
            if v.angle_deg is not None and _same_angle(v.angle_deg, float(angle_deg)):
                return v
        return None

    @property
    def angles_deg(self) -> list[float]:
        """Turn angles of the views, degrees, in view order (turntable projects)."""
        return [v.angle_deg for v in self.views if v.angle_deg is not None]

    def camera_of(self, view) -> Camera:
        """The camera (with pose) that took ``view``, named after the view."""
        v = self.view(view)
        if self.turntable is not None:
            return self.turntable.camera_at(v.angle_deg, v.name)
        c = self.rig[v.camera]
        return Camera(v.name, c.K, c.dist, c.world2cam, c.image_size, c.response)

    def image_size(self, view) -> tuple[int, int]:
        """``(width, height)`` in pixels of the photos of ``view``'s camera."""
        return self.camera_of(view).image_size

    def add_view(self, image, angle_deg: float | None = None, camera: str | None = None, *,
                 detections: Mapping | None = None, processed=None, replace: bool = False,
                 image_suffix: str = ".png", jpeg_quality: int = 95) -> View:
        """Add a photo as a new view, copying it into ``photos/`` (atomically).

        Parameters
        ----------
        image : path or ndarray
            A photo file (copied byte for byte) or a BGR/grey ``uint8`` image (encoded with
            ``image_suffix``).
        angle_deg : float
            Turn angle in degrees (turntable projects).
        camera : str
            Rig camera name (rig projects).
        detections : mapping, optional
            Automatic detections ``{marker: (x, y)}`` in pixels.
        processed : path or ndarray, optional
            The processed photo, stored beside it.
        replace : bool
            Replace an existing view at the same angle (or camera): its detections and edits go
            with it, its files are deleted by the next :meth:`save`.
        image_suffix : str
            ``.png`` (lossless, default) or ``.jpg`` for array images.

        Returns
        -------
        View
            Not saved yet: call :meth:`save`.
        """
        if self.turntable is not None:
            if angle_deg is None or camera is not None:
                raise ValueError("this is a turntable project: give angle_deg= (degrees), not camera=")
            angle_deg = float(angle_deg)
            if not (math.isfinite(angle_deg) and abs(angle_deg) <= MAX_COORDINATE):
                raise ValueError(f"angle_deg must be a finite number of degrees within +-{MAX_COORDINATE:g}, "
                                 f"got {angle_deg}")
            name = _format_angle(angle_deg)
            old = self.view_at(angle_deg)
            size = self.turntable.camera.image_size
            what = f"view at {angle_deg:g} deg"
        else:
            if camera is None or angle_deg is not None:
                raise ValueError("this is a rig project: give camera= (a rig camera name), not angle_deg=")
            if camera not in self.rig.names:
                raise ValueError(f"unknown camera {camera!r}; the rig has {self.rig.names}")
            name = str(camera)
            old = next((v for v in self.views if v.camera == camera), None)
            size = self.rig[camera].image_size
            what = f"view of camera {camera!r}"
        if old is not None and not replace:
            raise ValueError(f"the project already has a {what} ({old.image}); pass replace=True to retake it")
        det = self._check_markers(detections or {}, size, f"{what}: detections")
        taken = {v.image for v in self.views} | {v.processed for v in self.views if v.processed} | self._stale_files
        img_rel = self._store_image(image, name, "", size, what, taken, image_suffix, jpeg_quality)
        proc_rel = None
        if processed is not None:
            proc_rel = self._store_image(processed, name, "_processed", size, f"{what}: processed image",
                                         taken | {img_rel}, image_suffix, jpeg_quality)
        view = View(name, img_rel, angle_deg, None if angle_deg is not None else str(camera), det, [], proc_rel)
        if old is not None:
            i = next(i for i, v in enumerate(self.views) if v is old)
            self.views[i] = view
            self._stale_files.update(f for f in (old.image, old.processed) if f)
        else:
            self.views.append(view)
        return view

    def remove_view(self, view) -> None:
        """Remove a view; its photo files are deleted by the next :meth:`save`."""
        v = self.view(view)
        self.views = [w for w in self.views if w is not v]
        self._stale_files.update(f for f in (v.image, v.processed) if f)

    def _store_image(self, image, name, tag, size, what, taken, suffix, jpeg_quality) -> str:
        """Check an image's size and write it into photos/ under a name no view uses; return the relative path."""
        if isinstance(image, np.ndarray):
            arr = image
            suffix = suffix.lower()
            if suffix not in (".png", ".jpg", ".jpeg"):
                raise ValueError(f"{what}: image_suffix must be .png, .jpg or .jpeg, got {suffix!r}")
            if arr.dtype != np.uint8 or not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (1, 3, 4))):
                raise ValueError(f"{what}: image must be a uint8 array (H, W) or (H, W, 3), "
                                 f"got {arr.dtype} {arr.shape}")
            params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if suffix != ".png" else []
            ok, buf = cv2.imencode(suffix, arr, params)
            if not ok:
                raise ValueError(f"{what}: OpenCV could not encode the image as {suffix}")
            data = buf.tobytes()
        else:
            src = Path(image)
            if not src.is_file():
                raise ValueError(f"{what}: photo {src} does not exist")
            suffix = src.suffix.lower()
            if suffix not in IMAGE_SUFFIXES:
                raise ValueError(f"{what}: photo {src} is not a {'/'.join(IMAGE_SUFFIXES)} file")
            data = src.read_bytes()
            try:  # size and completeness checked before decoding
                arr = decode_image(data, src, cv2.IMREAD_UNCHANGED)
            except ValueError as e:
                raise ValueError(f"{what}: {e}") from None
        h, w = arr.shape[:2]
        if (w, h) != tuple(size):
            raise ValueError(f"{what}: image is {w}x{h} px but the camera is {size[0]}x{size[1]} px")
        stem = _file_stem(name) + tag
        rel = f"{PHOTOS_DIR}/{stem}{suffix}"
        k = 2
        while rel in taken:
            rel = f"{PHOTOS_DIR}/{stem}_{k}{suffix}"
            k += 1
        write_bytes(resolve_inside(self.root, rel, what), data)
        return rel

    # --- markers --------------------------------------------------------------------------
    def _check_name(self, marker, what: str) -> str:
        if not isinstance(marker, str) or marker not in self.markerset.names:
            raise ValueError(f"{what}: unknown marker {marker!r}; marker set {self.markerset.name!r} has "
                             f"{', '.join(self.markerset.names)}")
        return marker

    def _check_markers(self, markers: Mapping, size, what: str) -> dict:
        if not isinstance(markers, Mapping):
            raise ValueError(f"{what}: markers must be a mapping {{name: [x, y]}}, got {type(markers).__name__}")
        return {self._check_name(k, what): _check_xy(xy, size, f"{what}: marker {k!r}") for k, xy in markers.items()}

    def set_detections(self, view, markers: Mapping) -> View:
        """Replace a view's automatic detections ``{marker: (x, y)}`` (pixels); its edits are kept."""
        v = self.view(view)
        v.detected = self._check_markers(markers, self.image_size(v), f"view {v.name!r}: detections")
        return v

    def clear_edits(self, view) -> View:
        """Drop a view's manual edits (back to the automatic detections)."""
        v = self.view(view)
        v.edits = []
        return v

    def edit(self, view, *, delete: str | None = None, relabel: tuple[str, str] | None = None,
             move: tuple[str, float, float] | None = None) -> View:
        """Record one manual correction of a view's markers (kept when detection is re-run).

        Parameters
        ----------
        view : View, int or str
        delete : str
            Remove this (falsely identified) marker.
        relabel : (old, new)
            The point identified as ``old`` is really ``new`` (``new`` must not be present:
            delete it first).
        move : (name, x, y)
            Put ``name`` at pixel ``(x, y)``; adds it if the view lacks it.

        Returns
        -------
        View
            Not saved yet: call :meth:`save`.
        """
        v = self.view(view)
        given = [k for k, a in (("delete", delete), ("relabel", relabel), ("move", move)) if a is not None]
        if len(given) != 1:
            raise ValueError(f"edit takes exactly one of delete=, relabel=, move=; got {given or 'none'}")
        what = f"view {v.name!r}"
        current = v.markers
        if delete is not None:
            if delete not in current:
                raise ValueError(f"{what} has no marker {delete!r} to delete (it has {sorted(current)})")
            e = Edit("delete", delete)
        elif relabel is not None:
            try:
                old, new = relabel
            except (TypeError, ValueError):
                raise ValueError(f"{what}: relabel must be (old, new), got {relabel!r}") from None
            if old not in current:
                raise ValueError(f"{what} has no marker {old!r} to relabel (it has {sorted(current)})")
            self._check_name(new, what)
            if new in current and new != old:
                raise ValueError(f"{what} already has a marker {new!r}; "
                                 f"delete it before relabelling {old!r} as {new!r}")
            e = Edit("relabel", old, to=new)
        else:
            try:
                name, x, y = move
            except (TypeError, ValueError):
                raise ValueError(f"{what}: move must be (name, x, y), got {move!r}") from None
            self._check_name(name, what)
            e = Edit("move", name, xy=_check_xy((x, y), self.image_size(v), f"{what}: marker {name!r}"))
            if v.edits and v.edits[-1].op == "move" and v.edits[-1].marker == name:
                v.edits[-1] = e  # dragging a marker: keep only its last position
                return v
        v.edits.append(e)
        return v

    # --- geometry -------------------------------------------------------------------------
    def views_rig(self) -> Rig:
        """One camera per view, named after the view, in view order."""
        if not self.views:
            raise ValueError(f"project {self.root} has no views yet")
        return Rig([self.camera_of(v) for v in self.views], self.rig.world if self.rig is not None else "puppet")

    def observations(self) -> tuple[tuple[str, ...], np.ndarray, Rig]:
        """Identified markers of every view, ready for :func:`stillcap.geometry.triangulate`.

        Returns
        -------
        names : tuple of str, length n_markers
            Marker-set order.
        points_2d : ndarray, shape (n_views, n_markers, 2)
            Effective marker positions in pixels; NaN where a view did not identify a marker.
        rig : Rig
            The camera of every view (:meth:`views_rig`).
        """
        rig = self.views_rig()
        names = tuple(self.markerset.names)
        index = {n: i for i, n in enumerate(names)}
        pts = np.full((len(self.views), len(names), 2), np.nan)
        for k, v in enumerate(self.views):
            for n, xy in v.markers.items():
                if n not in index:
                    raise ValueError(f"view {v.name!r}: unknown marker {n!r} (marker set {self.markerset.name!r})")
                pts[k, index[n]] = xy
        return names, pts, rig

    def reconstruct(self, method: str = "dlt", refine: bool = True, outlier_px: float | None = None) -> Markers3D:
        """3D markers from the identified 2D markers (recomputed every time, never stored).

        Markers identified in fewer than two views come back as NaN and are listed in
        ``missing`` (the thesis's red entries). ``method``, ``refine`` and ``outlier_px`` go to
        :func:`stillcap.geometry.triangulate` (``"midpoint"`` is the thesis's method).
        """
        names, pts, rig = self.observations()
        tri = triangulate(rig, pts, method=method, refine=refine, outlier_px=outlier_px, min_views=2)
        ok = tri.ok
        missing = tuple(n for n, good in zip(names, ok) if not good)
        return Markers3D(names, tri.points, tri.n_views, tri.reproj_error_px, missing, tri)

    # --- images ---------------------------------------------------------------------------
    def image_path(self, view, processed: bool = False) -> Path:
        """Absolute path of a view's photo (or processed photo)."""
        v = self.view(view)
        rel = v.processed if processed else v.image
        if rel is None:
            raise ValueError(f"view {v.name!r} has no processed image")
        return resolve_inside(self.root, rel, f"view {v.name!r}: {'processed' if processed else 'image'}")

    def read_image(self, view, processed: bool = False, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
        """Decode a view's photo (BGR uint8); ValueError naming the file if missing, corrupt or of the wrong size."""
        v = self.view(view)
        path = self.image_path(v, processed)
        if not path.is_file():
            raise ValueError(f"view {v.name!r}: photo {path} does not exist")
        try:  # size and completeness checked before decoding
            img = read_image(path, flags)
        except ValueError as e:
            raise ValueError(f"view {v.name!r}: {e}") from None
        w, h = self.image_size(v)
        if img.shape[:2] != (h, w):
            raise ValueError(f"view {v.name!r}: photo {path} is {img.shape[1]}x{img.shape[0]} px "
                             f"but the camera is {w}x{h} px")
        return img

    def verify(self) -> None:
        """Decode every photo (slow); ValueError naming the first bad one."""
        for v in self.views:
            self.read_image(v)
            if v.processed:
                self.read_image(v, processed=True)

    # --- files ----------------------------------------------------------------------------
    def _markerset_entry(self):
        d = self.markerset.to_dict()
        for name, make in BUILTIN_MARKERSETS.items():
            if d == make().to_dict():
                return name
        return d

    def to_dict(self) -> dict:
        """The JSON content of ``project.json``."""
        d = {"format": PROJECT_FORMAT, "version": PROJECT_VERSION, "name": self.name, "units": dict(UNITS),
             "markerset": self._markerset_entry()}
        if self.skeleton is not None:
            from stillcap.body.bodyfiles import body_entry_dict

            d["skeleton"] = self._skeleton_file or body_entry_dict(self.skeleton)
        if self.turntable is not None:
            d["turntable"] = self.turntable.to_dict()
        else:
            d["rig"] = {"file": self.rig_file} if self.rig_file is not None else self.rig.to_dict()
        d["views"] = [v.to_dict() for v in self.views]
        if self.meta:
            d["meta"] = self.meta
        return d

    def _validate(self) -> None:
        names = [v.name for v in self.views]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"duplicate view names {dup}")
        for i, v in enumerate(self.views):
            for w in self.views[:i]:
                if v.angle_deg is not None and w.angle_deg is not None and _same_angle(v.angle_deg, w.angle_deg):
                    raise ValueError(f"views {w.name!r} and {v.name!r} have the same turn angle {v.angle_deg:g} deg")
                if v.camera is not None and v.camera == w.camera:
                    raise ValueError(f"views {w.name!r} and {v.name!r} are both from camera {v.camera!r}")
        for v in self.views:
            what = f"view {v.name!r}"
            if self.turntable is not None:
                if v.angle_deg is None or v.camera is not None:
                    raise ValueError(f"{what}: a turntable project's views need angle_deg (and no camera)")
            else:
                if v.camera is None or v.angle_deg is not None:
                    raise ValueError(f"{what}: a rig project's views need camera (and no angle_deg)")
                if v.camera not in self.rig.names:
                    raise ValueError(f"{what}: unknown camera {v.camera!r}; the rig has {self.rig.names}")
            v.image = safe_relpath(v.image, f"{what}: image")
            if v.processed is not None:
                v.processed = safe_relpath(v.processed, f"{what}: processed")
            size = self.image_size(v)
            self._check_markers(v.detected, size, f"{what}: detections")
            for e in v.edits:
                self._check_name(e.marker, f"{what}: {e.op} edit")
                if e.to is not None:
                    self._check_name(e.to, f"{what}: relabel edit")
            self._check_markers(v.markers, size, f"{what}: markers")

    def save(self) -> Path:
        """Write ``project.json`` atomically (then delete the photos of removed or retaken views)."""
        self._validate()
        text = dumps_json(self.to_dict()) + "\n"
        self.root.mkdir(parents=True, exist_ok=True)
        write_text(self.path, text)
        used = {v.image for v in self.views} | {v.processed for v in self.views if v.processed}
        for rel in sorted(self._stale_files - used):
            try:
                resolve_inside(self.root, rel, "old photo").unlink(missing_ok=True)
            except (OSError, ValueError):
                pass  # a stale photo that cannot be deleted is harmless
        self._stale_files = set()
        return self.path

    @classmethod
    def load(cls, folder) -> Project:
        """Open a project (``folder`` is the project folder or its ``project.json``) and validate it.

        Raises
        ------
        ValueError
            Naming the file, view, marker or camera at fault: missing folder or file, corrupt JSON,
            unknown format or newer version, unsafe paths, missing photos, unknown markers or cameras.
        """
        root = Path(folder)
        if root.name == PROJECT_FILE and root.is_file():
            root = root.parent
        pfile = root / PROJECT_FILE
        if not root.is_dir():
            raise ValueError(f"project folder {root} does not exist")
        if not pfile.is_file():
            raise ValueError(f"{pfile} does not exist: {root} is not a stillcap project")
        d = read_json(pfile)
        where = f"{pfile}: "
        if not isinstance(d, dict) or d.get("format") != PROJECT_FORMAT:
            raise ValueError(f"{where}not a stillcap puppet project (expected \"format\": \"{PROJECT_FORMAT}\")")
        version = d.get("version")
        if isinstance(version, int) and not isinstance(version, bool) and version > PROJECT_VERSION:
            raise ValueError(f"{where}project version {version} is newer than this stillcap reads ({PROJECT_VERSION})")
        f = validate(ProjectFile, d, str(pfile))
        if any(f.units.get(k, v) != v for k, v in UNITS.items()):
            raise ValueError(f"{where}units: must be {UNITS}, got {f.units!r}")
        markerset = _load_markerset(root, f.markerset, where, str(pfile))
        skeleton = skeleton_file = None
        if d.get("skeleton") is not None:
            from stillcap.body.bodyfiles import body_entry

            skeleton = body_entry(d["skeleton"], "skeleton", root, str(pfile), str(pfile), "skeleton")
            if isinstance(d["skeleton"], dict) and set(d["skeleton"]) == {"file"}:
                skeleton_file = dict(d["skeleton"])
        markerset.check_skeleton(skeleton or Skeleton.puppet())  # its bones are the skeleton's (it is posed)
        turntable = rig = rig_file = None
        if (f.turntable is None) == (f.rig is None):
            raise ValueError(f"{where}needs exactly one of \"turntable\" and \"rig\"")
        if f.turntable is not None:
            turntable = TurntableSetup.from_dict(d["turntable"], where)
        else:
            rig, rig_file = _load_rig(root, d["rig"], where)
        views = [_view_from_entry(vd, where, i) for i, vd in enumerate(f.views)]
        meta = f.meta
        name = f.name if f.name is not None else root.name
        project = cls(root, markerset, turntable, rig, views, name, rig_file, meta, skeleton=skeleton)
        project._skeleton_file = skeleton_file
        try:
            project._validate()
        except ValueError as e:
            raise ValueError(f"{where}{e}") from None
        for v in views:
            for rel, kind in ((v.image, "photo"), (v.processed, "processed photo")):
                if rel is None:
                    continue
                p = resolve_inside(root, rel, f"{where}view {v.name!r}: {kind}")
                if not p.is_file():
                    raise ValueError(f"{where}view {v.name!r}: {kind} {p} does not exist")
                try:  # header size and completeness, without decoding (files/images.py)
                    check_image_file(p)
                except ValueError as e:
                    raise ValueError(f"{where}view {v.name!r}: {kind}: {e}") from None
        return project


def _load_markerset(root: Path, entry, where: str, source: str) -> MarkerSet:
    if isinstance(entry, str):
        if entry not in BUILTIN_MARKERSETS:
            raise ValueError(f"{where}unknown built-in marker set {entry!r} (built-in: {sorted(BUILTIN_MARKERSETS)}; "
                             "use {\"file\": \"markers.json\"} for a marker-set file)")
        return BUILTIN_MARKERSETS[entry]()
    if isinstance(entry, dict) and set(entry) == {"file"}:
        path = resolve_inside(root, entry["file"], f"{where}markerset file")
        if not path.is_file():
            raise ValueError(f"{where}marker-set file {path} does not exist")
        return MarkerSet.load(path)
    if isinstance(entry, dict) and entry.get("format") == "stillcap-markerset":
        return MarkerSet.from_dict(entry, source=source, prefix=("markerset",))
    raise ValueError(f"{where}\"markerset\" must be a built-in name, {{\"file\": ...}} or an embedded marker set")


def _load_rig(root: Path, entry, where: str) -> tuple[Rig, str | None]:
    if isinstance(entry, dict) and set(entry) == {"file"}:
        rel = safe_relpath(entry["file"], f"{where}rig file")
        path = resolve_inside(root, rel, f"{where}rig file")
        if not path.is_file():
            raise ValueError(f"{where}rig file {path} does not exist")
        return Rig.load(path), rel
    if isinstance(entry, dict) and entry.get("format") == RIG_FORMAT:
        return Rig.from_dict(entry, f"{where}rig: "), None
    raise ValueError(f"{where}\"rig\" must be {{\"file\": \"rig.json\"}} or an embedded stillcap rig")
