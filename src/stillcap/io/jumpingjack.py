"""The thesis's "JumpingJack" project files (``.juja``): import into and export from stillcap.

Reconstructed from the thesis (seed 002, section 7.1.2; the extracted text spaces out every
letter, e.g. ``<J J P r o j e c t name=" my_project . j u j a ">``)::

    <?xml version="1.0" encoding="UTF-8"?>
    <JJProject name="my_project.juja">
      <image name="0" normal_src="my_project_0.jpg" pro_src="my_project_0p.jpg">
        <marker name="leg.L1" x="380" y="267"/>
        <marker name="head.1" x="349" y="23"/>
      </image>
      <image name="30" normal_src="my_project_30.jpg" pro_src="my_project_30p.jpg">
        <marker name="leg.R1" x="313" y="262"/>
      </image>
    </JJProject>

- ``JJProject/@name``: the project file's own name.
- ``image/@name``: the turn angle in **degrees** (the thesis writes integers: 0, 30, ..., 330).
  For a stillcap rig project (several cameras, no turntable) stillcap writes the camera name
  instead, and :func:`import_jumpingjack` reads it so when given ``rig=``.
- ``image/@normal_src``: the photo; ``image/@pro_src``: the processed photo (outline image with
  the found circles). Both are JPEG files in the same folder as the ``.juja`` file, named
  ``<project>_<angle>.jpg`` and ``<project>_<angle>p.jpg``.
- ``marker``: an identified marker, ``name`` from the marker set, ``x``, ``y`` its centre in
  **pixels**, origin at the top-left of the image, x right, y down (thesis section 4.1.2). The
  thesis's program wrote integers (Hough accumulator cells, i.e. pixel indices), which are
  exactly stillcap's pixel coordinates (origin at the centre of the top-left pixel): the
  mapping is the identity, ``x_stillcap = x``, ``y_stillcap = y``.
- 3D data is not stored; it is recomputed (:meth:`Project.reconstruct`).

The turntable geometry and camera intrinsics were constants of the thesis's program (400 mm,
80 mm, fx = 859.016, ...); they are not in the file. :func:`import_jumpingjack` takes them as
``turntable=`` (default: the thesis's setup). Manual edits are not representable either: export
writes each view's effective markers, which re-import as automatic detections.

Security: files are parsed only with :mod:`defusedxml` with DTDs forbidden (a JumpingJack file
never has one), so entity expansion ("billion laughs") and external entities are refused; files
larger than :data:`MAX_XML_BYTES` are refused; every file attribute must be a relative path
that stays in the ``.juja`` file's folder (no absolute paths, no ``..``, no symlink out).
"""

from __future__ import annotations

import math
import shutil
import xml.etree.ElementTree as ET  # building only; untrusted input is parsed with defusedxml
from dataclasses import dataclass, field
from pathlib import Path

import defusedxml
import defusedxml.ElementTree as DET

from stillcap.body.markerset import MarkerSet
from stillcap.camera import Rig
from stillcap.files.atomic import atomic_path, write_bytes
from stillcap.files.schema import MAX_COORDINATE
from stillcap.io.project import Project, TurntableSetup, resolve_inside

__all__ = ["JJ_SUFFIX", "MAX_XML_BYTES", "JJImage", "JJProjectFile", "read_jumpingjack", "parse_jumpingjack",
           "jumpingjack_xml", "import_jumpingjack", "export_jumpingjack", "exported_files"]

JJ_SUFFIX = ".juja"
#: Largest ``.juja`` file read (bytes); a real one is a few kilobytes.
MAX_XML_BYTES = 16 * 1024 * 1024


@dataclass
class JJImage:
    """One ``<image>`` element.

    Parameters
    ----------
    name : str
        Turn angle in degrees as written (``"30"``), or a camera name.
    normal_src : str
        Photo file, relative to the ``.juja`` file's folder.
    pro_src : str, optional
        Processed photo file.
    markers : dict
        ``{marker name: (x, y)}`` in pixels, in file order.
    """

    name: str
    normal_src: str
    pro_src: str | None = None
    markers: dict = field(default_factory=dict)

    @property
    def angle_deg(self) -> float:
        """``name`` as a turn angle in degrees (ValueError if it is not a number)."""
        try:
            a = float(self.name)
        except ValueError:
            raise ValueError(f"name {self.name!r} is not a turn angle in degrees") from None
        if not (math.isfinite(a) and abs(a) <= MAX_COORDINATE):
            raise ValueError(f"name {self.name!r}: the turn angle must be finite and within +-{MAX_COORDINATE:g} "
                             "degrees")
        return a


@dataclass
class JJProjectFile:
    """The content of a ``.juja`` file; ``folder`` is where its relative file names point."""

    name: str
    images: list[JJImage] = field(default_factory=list)
    folder: Path | None = None


def _number(text: str | None, what: str) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number, got {text!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{what} must be finite, got {text!r}")
    return v


def _fmt(v: float) -> str:
    """Shortest text that reads back as the same float; whole numbers without '.0' (as the thesis)."""
    s = repr(float(v))
    return s[:-2] if s.endswith(".0") else s


def parse_jumpingjack(data: bytes, source: str = "<juja>") -> JJProjectFile:
    """Parse the bytes of a ``.juja`` file (defusedxml, DTDs forbidden).

    Raises
    ------
    ValueError
        Naming ``source``: a DTD or entity declaration (refused: billion laughs, external
        entities), malformed XML, a root other than ``JJProject``, missing attributes, a
        non-numeric coordinate, a marker listed twice in one image, an image listed twice.
    """
    if len(data) > MAX_XML_BYTES:
        raise ValueError(f"{source}: {len(data)} bytes is too large for a JumpingJack project (limit {MAX_XML_BYTES})")
    try:
        root = DET.fromstring(data, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    except defusedxml.DefusedXmlException as e:
        raise ValueError(f"{source}: refused: the file declares a DTD or entities ({type(e).__name__}); "
                         "JumpingJack project files never do, and expanding them is unsafe") from None
    except ET.ParseError as e:
        raise ValueError(f"{source} is not well-formed XML: {e}") from None
    if root.tag != "JJProject":
        raise ValueError(f"{source}: not a JumpingJack project (root element <{root.tag}>, expected <JJProject>)")
    out = JJProjectFile(root.get("name", ""))
    seen: set[str] = set()
    for i, im in enumerate(root.findall("image")):
        name = (im.get("name") or "").strip() or None
        where = f"{source}: image #{i}" + (f" ({name!r})" if name is not None else "")
        if not name:
            raise ValueError(f"{where}: missing the name attribute (the turn angle in degrees)")
        if name in seen:
            raise ValueError(f"{where}: listed twice")
        seen.add(name)
        src = (im.get("normal_src") or "").strip()
        if not src:
            raise ValueError(f"{where}: missing the normal_src attribute (the photo)")
        img = JJImage(name, src, (im.get("pro_src") or "").strip() or None)
        for mk in im.findall("marker"):
            mname = (mk.get("name") or "").strip()
            if not mname:
                raise ValueError(f"{where}: a marker has no name attribute")
            if mname in img.markers:
                raise ValueError(f"{where}: marker {mname!r} is listed twice")
            img.markers[mname] = (_number(mk.get("x"), f"{where}: marker {mname!r} x"),
                                  _number(mk.get("y"), f"{where}: marker {mname!r} y"))
        out.images.append(img)
    return out


def read_jumpingjack(path) -> JJProjectFile:
    """Read a ``.juja`` file and check that every file it names is a safe relative path that exists.

    Raises
    ------
    ValueError
        As :func:`parse_jumpingjack`, plus: the file is missing, a file attribute is absolute,
        contains ``..`` or leads out of the folder through a symlink, a photo is missing.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"JumpingJack project {path} does not exist")
    size = path.stat().st_size
    if size > MAX_XML_BYTES:
        raise ValueError(f"{path}: {size} bytes is too large for a JumpingJack project (limit {MAX_XML_BYTES})")
    jj = parse_jumpingjack(path.read_bytes(), str(path))
    jj.folder = path.parent
    for i, im in enumerate(jj.images):
        where = f"{path}: image #{i} ({im.name!r})"
        p = resolve_inside(jj.folder, im.normal_src, f"{where}: normal_src")
        if not p.is_file():
            raise ValueError(f"{where}: photo {p} does not exist")
        if im.pro_src is not None:
            resolve_inside(jj.folder, im.pro_src, f"{where}: pro_src")
    return jj


def import_jumpingjack(path, folder, *, turntable: TurntableSetup | None = None, rig: Rig | None = None,
                       markerset: MarkerSet | str = "puppet-16", name: str | None = None) -> Project:
    """Make a stillcap project in ``folder`` from a JumpingJack ``.juja`` file.

    The photos (and processed photos, where present) are copied into ``folder/photos``; the
    markers become each view's automatic detections. ``project.json`` is written last, so a
    failed import leaves no project behind.

    Parameters
    ----------
    path : path
        The ``.juja`` file.
    folder : path
        New project folder (must not already hold a project).
    turntable : TurntableSetup, optional
        Geometry and intrinsics of the capture (default: the thesis's, which its files assume).
    rig : Rig, optional
        Read image names as camera names of this rig instead of turn angles.
    markerset : MarkerSet or str
        Marker names allowed (default: the thesis's 16 beads).
    name : str, optional
        Project name (default: the file's ``JJProject/@name`` without ``.juja``).
    """
    path = Path(path)
    jj = read_jumpingjack(path)
    if rig is not None and turntable is not None:
        raise ValueError("give turntable= or rig=, not both")
    if name is None:
        name = jj.name[:-len(JJ_SUFFIX)] if jj.name.endswith(JJ_SUFFIX) else (jj.name or path.stem)
    project = Project.create(folder, turntable=turntable if rig is None else None, rig=rig,
                             markerset=markerset, name=name, save=False)
    for i, im in enumerate(jj.images):
        where = f"{path}: image #{i} ({im.name!r})"
        pro = None
        if im.pro_src is not None:
            p = resolve_inside(jj.folder, im.pro_src, f"{where}: pro_src")
            pro = p if p.is_file() else None  # a processed photo can be made again; its absence is no error
        try:
            key = {"camera": im.name} if rig is not None else {"angle_deg": im.angle_deg}
            project.add_view(resolve_inside(jj.folder, im.normal_src, f"{where}: normal_src"),
                             detections=im.markers, processed=pro, **key)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
    project.save()
    return project


def jumpingjack_xml(project: Project, file_names: dict | None = None, name: str = "project.juja",
                    round_pixels: bool = False) -> bytes:
    """The ``.juja`` XML of a project (UTF-8 bytes, with the thesis's XML declaration).

    Parameters
    ----------
    file_names : dict, optional
        ``{view name: (normal_src, pro_src or None)}``; default: the project's own paths.
    name : str
        ``JJProject/@name``.
    round_pixels : bool
        Write whole pixels, as the thesis's program did (default: exact values).
    """
    root = ET.Element("JJProject", {"name": name})
    for v in project.views:
        normal, pro = (file_names or {}).get(v.name, (v.image, v.processed))
        attrs = {"name": _fmt(v.angle_deg) if v.angle_deg is not None else v.camera, "normal_src": normal}
        if pro is not None:
            attrs["pro_src"] = pro
        el = ET.SubElement(root, "image", attrs)
        for m, (x, y) in v.markers.items():
            if round_pixels:
                x, y = round(x), round(y)
            ET.SubElement(el, "marker", {"name": m, "x": _fmt(x), "y": _fmt(y)})
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode("utf-8") + b"\n"


def _juja_path(path) -> Path:
    path = Path(path)
    return path if path.suffix.lower() == JJ_SUFFIX else path.with_name(path.name + JJ_SUFFIX)


def _photo_plan(project: Project, path: Path) -> dict:
    """``{view name: ((source, destination) or None for the photo, the same for the processed
    photo)}`` of an export to the ``.juja`` file ``path`` (the thesis's naming)."""
    folder, stem = path.parent, path.stem
    plan: dict = {}
    taken: set = set()
    for v in project.views:
        label = _fmt(v.angle_deg) if v.angle_deg is not None else v.camera
        label = "".join(c if c.isalnum() or c in "._+-" else "_" for c in label)
        files = []
        for rel, tag in ((v.image, ""), (v.processed, "p")):
            if rel is None:
                files.append(None)
                continue
            src = project.image_path(v, processed=bool(tag))
            if not src.is_file():
                raise ValueError(f"view {v.name!r}: photo {src} does not exist")
            out = f"{stem}_{label}{tag}{src.suffix.lower()}"
            if out in taken:
                raise ValueError(f"view {v.name!r}: its exported file name {out!r} clashes with another view's "
                                 "(camera names that differ only in special characters)")
            taken.add(out)
            files.append((src, folder / out))
        plan[v.name] = tuple(files)
    return plan


def exported_files(project: Project, path) -> list[Path]:
    """The photo files :func:`export_jumpingjack` writes beside the ``.juja`` file ``path``
    (not those that are already the project's own photos)."""
    path = _juja_path(path)
    return [dst for files in _photo_plan(project, path).values() for e in files if e is not None
            for src, dst in [e] if not (dst.exists() and dst.resolve() == src.resolve())]


def export_jumpingjack(project: Project, path, round_pixels: bool = False) -> Path:
    """Write a project as a JumpingJack ``.juja`` file with its photos beside it.

    Photos are copied (byte for byte, keeping their format) as ``<stem>_<angle><ext>`` and
    processed photos as ``<stem>_<angle>p<ext>``, the thesis's naming; the XML is written last.
    Every file is written atomically.

    Parameters
    ----------
    project : Project
    path : path
        The ``.juja`` file to write (the suffix is added if missing).
    round_pixels : bool
        Whole-pixel coordinates, as the thesis's program wrote (loses sub-pixel precision).

    Returns
    -------
    Path
        The ``.juja`` file.
    """
    path = _juja_path(path)
    folder = path.parent
    folder.mkdir(parents=True, exist_ok=True)
    plan = _photo_plan(project, path)
    for view in plan.values():
        for entry in view:
            if entry is not None:
                src, dst = entry
                if not (dst.exists() and dst.resolve() == src.resolve()):
                    with atomic_path(dst) as tmp:
                        shutil.copyfile(src, tmp)
    names = {v: tuple(None if e is None else e[1].name for e in files) for v, files in plan.items()}
    write_bytes(path, jumpingjack_xml(project, names, path.name, round_pixels))
    return path
