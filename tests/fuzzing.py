"""Property-based testing of the files a user gives (importable as ``fuzzing``; tests/ is on the
pythonpath): strategies for arbitrary JSON and for mutations of a valid file, a seed of every
format, and the one property every reader must keep: a file either loads, or the reader raises
``ValueError`` in one line naming the file. ``tools/fuzz_files.py`` runs the same properties longer.

Formats (:data:`FORMATS`): skeleton, marker set, project.json, puppet result, label overrides,
palette, marker-ball palette and JumpingJack XML. capture.json and rig.json (and the camera inside
a project's turntable) are another part's; mutations leave the turntable camera alone.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

#: The examples each property runs in the test suite (tools/fuzz_files.py runs more).
CI = settings(max_examples=60, deadline=None, database=None, suppress_health_check=list(HealthCheck))

# --- strategies ---------------------------------------------------------------------------------
#: Numbers that break readers: huge, tiny, negative, non-finite, the wrong type.
SPECIAL_NUMBERS = [0, -1, 1, 0.5, -0.0, 1e308, -1e308, 1e-320, 2 ** 63, 1e6 + 1, math.nan, math.inf, -math.inf,
                   True, False, None, "abc", "1.5", "", [], {}, [1, 2], [1, 2, 3, 4], {"a": 1}]

_leaves = (st.none() | st.booleans() | st.integers(-10 ** 12, 10 ** 12) | st.floats(allow_nan=True)
           | st.text(max_size=12) | st.sampled_from(SPECIAL_NUMBERS).map(copy.deepcopy))
#: Any JSON value (NaN and infinity included: Python's json reads them).
json_values = st.recursive(_leaves, lambda kids: st.lists(kids, max_size=5)
                           | st.dictionaries(st.text(max_size=8), kids, max_size=5), max_leaves=25)


def _paths(value, prefix=()):
    """Every key path inside a JSON value (the root is ``()``)."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, (*prefix, i))


def _get(value, path):
    for k in path:
        value = value[k]
    return value


@st.composite
def mutations(draw, seed, frozen: tuple = (), n_max: int = 3):
    """A copy of ``seed`` (a JSON value) with 1..n_max mutations at random key paths: a value
    replaced (by a special or arbitrary value, a number scaled or negated), a key deleted or
    added, a list entry duplicated or dropped. Paths starting with one of ``frozen`` stay."""
    doc = copy.deepcopy(seed)
    for _ in range(draw(st.integers(1, n_max))):
        paths = [p for p in _paths(doc) if p and not any(p[:len(f)] == f for f in frozen)]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _get(doc, path[:-1]), path[-1]
        kind = draw(st.sampled_from(["special", "arbitrary", "number", "delete", "add", "duplicate"]))
        old = parent[key]
        if kind == "special":
            parent[key] = copy.deepcopy(draw(st.sampled_from(SPECIAL_NUMBERS)))
        elif kind == "arbitrary":
            parent[key] = draw(json_values)
        elif kind == "number" and isinstance(old, (int, float)) and not isinstance(old, bool):
            parent[key] = old * draw(st.sampled_from([-1, 0, 2, 1e3, 1e300, 1e-300])) + draw(st.sampled_from([0, 1]))
        elif kind == "delete":
            del parent[key]
        elif kind == "add" and isinstance(old, dict):
            old[draw(st.text(max_size=8))] = draw(json_values)
        elif kind == "add" and isinstance(old, list):
            old.append(draw(json_values))
        elif kind == "duplicate" and isinstance(parent, list):
            parent.append(copy.deepcopy(old))
        else:
            parent[key] = draw(json_values)
    return doc


@st.composite
def json_files(draw, seed, frozen: tuple = ()):
    """What a user might hand over instead of ``seed``: mostly mutations of it, sometimes any JSON."""
    if draw(st.integers(0, 9)) == 0:
        return draw(json_values)
    return draw(mutations(seed, frozen))


def dumps(value) -> str:
    """JSON text of a value (NaN and infinity written as Python's json writes them)."""
    return json.dumps(value, allow_nan=True)


# --- seeds ---------------------------------------------------------------------------------------
W, H = 640, 480


def seed_skeleton() -> dict:
    from stillcap.body import Skeleton

    return Skeleton.puppet().to_dict("mm")


def seed_markerset() -> dict:
    from stillcap.body.markerset import MarkerSet

    return MarkerSet.puppet("puppet-20").to_dict("mm")


def seed_result() -> dict:
    """A puppet result as ``stillcap puppet run --out`` writes what exports read (a pose of the
    puppet turned and bent, its 16 markers, one of them missing)."""
    from scipy.spatial.transform import Rotation

    from stillcap.body import Pose, Skeleton
    from stillcap.body.markerset import MarkerSet

    sk, ms = Skeleton.puppet(), MarkerSet.puppet()
    local = np.tile(np.eye(3), (sk.n_joints, 1, 1))
    local[sk.index("l-elbow")] = Rotation.from_euler("y", -40, degrees=True).as_matrix()
    root2world = sk.rest_root2world()
    root2world[:3, :3] = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    pose = Pose(sk, root2world, local)
    pts = ms.positions(pose)
    markers = [{"name": n, "position": None if k == 3 else p.tolist()} for k, (n, p) in enumerate(zip(ms.names, pts))]
    joints = [{"name": n, "position": x.tolist(), "local_rotation": r.tolist()}
              for n, x, r in zip(sk.names, pose.positions, pose.local_rotations)]
    return {"format": "stillcap-puppet-result", "version": 1, "kind": "puppet", "markers": markers,
            "joints": joints, "root2world": root2world.tolist(), "skeleton": sk.to_dict()}


def seed_overrides() -> dict:
    return {"format": "stillcap-label-overrides", "version": 1, "tolerance_mm": 3,
            "overrides": [{"flash": 0, "position_m": [0.1, 1.2, -0.3], "label": "index.nail"},
                          {"flash": 1, "position_m": [0.12, 1.25, -0.31], "delete": True, "tolerance_mm": 2,
                           "comment": "a stray point"}]}


def seed_palette() -> dict:
    from stillcap.body.markerset import MarkerSet
    from stillcap.detect.palette import Palette

    return Palette.from_markerset(MarkerSet.puppet()).to_dict()


def seed_bgr_palette() -> dict:
    return {"red": [30, 30, 220], "green": [40, 200, 40], "blue": [210, 60, 20]}


def make_project(folder: Path):
    """A small turntable project: three views of black 640x480 photos with detections and edits."""
    from stillcap.io.project import Project

    p = Project.create(folder)
    for k, a in enumerate((0.0, 30.0, 60.0)):
        img = np.zeros((H, W, 3), np.uint8)
        p.add_view(img, angle_deg=a, detections={"head.1": (300.0 + k, 40.0), "head.2": (310.0, 60.0 + k),
                                                 "torso.1": (320.0, 120.5), "arm.L1": (200.0, 100.0)})
    p.edit(1, delete="arm.L1")
    p.edit(2, relabel=("arm.L1", "arm.R1"))
    p.edit(0, move=("leg.L1", 330.0, 300.0))
    p.save()
    return p


# --- readers ----------------------------------------------------------------------------------
@dataclass
class Format:
    """A file format under test: its file name, its seed and its reader (which gets the path)."""

    file_name: str
    seed: Callable[[], dict]
    read: Callable[[Path], object]
    frozen: tuple = ()


def _read_markerset(path):
    from stillcap.body import Skeleton
    from stillcap.body.markerset import MarkerSet

    ms = MarkerSet.load(path)
    ms.check_skeleton(Skeleton.puppet())
    return ms


def _read_skeleton(path):
    from stillcap.body import Skeleton

    return Skeleton.load(path).rest_pose().positions


def _read_result(path):
    from stillcap.io.export import as_export_data
    from stillcap.io.puppet_result import load_result

    return as_export_data(load_result(path))


def _read_overrides(path):
    from stillcap.body.hand_label import read_label_overrides

    return read_label_overrides(path)


def _read_palette(path):
    from stillcap.detect.palette import Palette

    return Palette.load(path)


def _read_bgr_palette(path):
    from stillcap.detect.palette import read_bgr_palette

    return read_bgr_palette(path)


FORMATS = {
    "skeleton": Format("skeleton.json", seed_skeleton, _read_skeleton),
    "markerset": Format("markers.json", seed_markerset, _read_markerset),
    "result": Format("result.json", seed_result, _read_result),
    "overrides": Format("overrides.json", seed_overrides, _read_overrides),
    "palette": Format("palette.json", seed_palette, _read_palette),
    "bgr-palette": Format("balls.json", seed_bgr_palette, _read_bgr_palette),
}


def check_one_line(message: str, name: str) -> None:
    """The property of a refusal: one line that names the file."""
    assert "\n" not in message, f"more than one line: {message!r}"
    assert name in message, f"the message does not name {name}: {message!r}"


def outcome(read, path: Path) -> str:
    """``"ok"`` or ``"refused"``; any other exception, or a refusal that does not name the file in
    one line, fails (raises AssertionError or the exception itself)."""
    try:
        read(path)
    except ValueError as e:
        check_one_line(str(e), path.name)
        return "refused"
    return "ok"


# --- projects and JumpingJack files ------------------------------------------------------------
#: The turntable camera is read by ``Camera.from_dict`` (the rig format's part).
PROJECT_FROZEN = (("turntable", "camera"),)


def read_project(folder: Path):
    from stillcap.io.project import Project

    p = Project.load(folder)
    return p.observations() if p.views else p


@st.composite
def xml_mutations(draw, text: str):
    """A JumpingJack file's XML with 1..3 mutations: attribute values replaced or removed,
    elements removed or duplicated, or the text cut short."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(text)
    for _ in range(draw(st.integers(1, 3))):
        elements = list(root.iter())
        el = draw(st.sampled_from(elements))
        kind = draw(st.sampled_from(["value", "remove-attr", "remove", "duplicate", "add-attr"]))
        if kind == "value" and el.attrib:
            key = draw(st.sampled_from(sorted(el.attrib)))
            el.set(key, draw(st.sampled_from(["", "nan", "inf", "-1e308", "1e308", "abc", "../x.png", "/etc/passwd",
                                              "0", "30", "head.1", "nose", "9999", " "])
                                | st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")),
                                          max_size=10)))
        elif kind == "remove-attr" and el.attrib:
            del el.attrib[draw(st.sampled_from(sorted(el.attrib)))]
        elif kind == "add-attr":
            el.set("name", draw(st.text(alphabet="abc0123456789.-", max_size=6)))
        else:
            parent = next((p for p in root.iter() if el in list(p)), None)
            if parent is not None and kind == "remove":
                parent.remove(el)
            elif parent is not None:
                parent.append(copy.deepcopy(el))
    out = ET.tostring(root, encoding="unicode")
    if draw(st.integers(0, 9)) == 0:
        out = out[:draw(st.integers(0, len(out)))]
    return out


def written(tmp_path: Path, doc: dict, change: Callable, name: str) -> Path:
    """``doc`` changed in place by ``change`` and written as ``tmp_path / name``."""
    change(doc)
    path = tmp_path / name
    path.write_text(dumps(doc))
    return path


def check_any_file(tmp_path: Path, name: str) -> None:
    """The property of format ``name``: any JSON file (and any mutation of its seed) loads, or is
    refused in one line naming the file."""
    fmt = FORMATS[name]

    @CI
    @given(json_files(fmt.seed(), fmt.frozen))
    def prop(doc):
        path = tmp_path / fmt.file_name
        path.write_text(dumps(doc))
        outcome(fmt.read, path)

    prop()
