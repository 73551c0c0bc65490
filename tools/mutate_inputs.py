"""Random mutation campaign over capture folders: each case copies a kept capture, makes its
``capture.json``, its ``rig.json`` or one of its photos INVALID by construction, and runs the
command that reads it (``stillcap pitch``, ``hand``, ``markers`` or ``puppet run``, by the
capture's kind) in-process. The only good outcome is exit status 2 with exactly one line on
stderr; exit 0 (an invalid input accepted), a traceback, or an exit 2 with more or fewer lines
are failures.

    python tools/mutate_inputs.py --cases 1000 --seed 0                 # the kept captures in /tmp/kept
    python tools/mutate_inputs.py --cases 200 --out fails.json CAPTURE...

It prints a table of counts per mutation kind and outcome, and writes the failing cases (capture,
file, key path, value, command, outcome, stderr, traceback) to a JSON file. Why each mutation is
invalid is said beside it (``docs/capture-folder.md``, ``docs/rig-format.md`` for the limits).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import random
import shutil
import struct
import sys
import tempfile
import traceback
import warnings
import zlib
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

#: The command that reads a capture of each kind.
COMMANDS = {"pitch": ["pitch"], "hand": ["hand"], "markers": ["markers"], "puppet": ["puppet", "run"]}
#: The commands that analyse one kind only (``stillcap markers`` finds marker balls in any capture).
KIND_CHECKED = ("pitch", "hand", "puppet")
KINDS = ("chessboard", "charuco", "calibration-object", "rig-boards", "markers", "pitch", "hand", "puppet")
OUTCOMES = ("ok", "exit0", "traceback", "lines", "other")
NAN, INF = float("nan"), float("inf")


# --- the typed slots of the two files (what each key accepts) -----------------------------------
@dataclass(frozen=True)
class Slot:
    """What a key accepts: ``type`` is num, int, str (a non-empty name), text (any string),
    path, camref (a rig camera's name), const (one value), bool, obj, list, str_or_obj;
    numbers lie in ``[lo, hi]`` (``lo`` excluded with ``open_lo``), or equal ``exact``."""

    type: str
    lo: float = -math.inf
    hi: float = math.inf
    open_lo: bool = False
    exact: float | None = None
    length: tuple = ()  # lists: the lengths allowed (empty: any)
    nullable: bool = False


def _num(lo, hi, open_lo=False):
    return Slot("num", lo, hi, open_lo)


CONST, BOOL, OBJ, TEXT, STR, PATH, CAMREF = (Slot(t) for t in ("const", "bool", "obj", "text", "str", "path", "camref"))


def capture_slots(d: dict) -> list[tuple[tuple, Slot]]:
    """The typed keys of a ``capture.json`` content (io/_capture_schema.py)."""
    out = [(("format",), CONST), (("version",), Slot("int", 1, 1)), (("kind",), CONST), (("rig",), PATH),
           (("images",), Slot("list"))]
    if isinstance(d.get("units"), dict):
        out += [(("units",), OBJ)] + [(("units", k), CONST) for k in d["units"] if k in ("length", "time", "frequency", "angle")]
    if isinstance(d.get("truth"), str):
        out.append((("truth",), Slot("path", nullable=True)))
    timing = {"strobe_hz": _num(0, 1e6, True), "shutter_s": _num(0, 3600, True), "first_flash_s": _num(0, 3600),
              "n_flashes": Slot("int", 0, 100_000)}
    meta = {"pair": STR, "angle_deg": _num(-1e4, 1e4), "view": Slot("int", 0, 1e6), "instant": Slot("int", 0, 1e6)}
    for i, im in enumerate(d.get("images", [])):
        out += [(("images", i), OBJ), (("images", i, "file"), PATH), (("images", i, "camera"), CAMREF)]
        out += [(("images", i, k), s) for k, s in timing.items() if k in im]
        if isinstance(im.get("meta"), dict):
            out.append((("images", i, "meta"), OBJ))
            out += [(("images", i, "meta", k), s) for k, s in meta.items() if k in im["meta"]]
    for k, s in (("description", TEXT), ("synthetic", BOOL), ("rig_calibrated", BOOL), ("target", OBJ),
                 ("markerset", Slot("str_or_obj")), ("skeleton", Slot("str_or_obj"))):
        if k in d:
            out.append(((k,), s))
    if isinstance(d.get("pairs"), dict):
        out.append((("pairs",), OBJ))
        for name, cams in d["pairs"].items():
            out += [(("pairs", name), Slot("list", length=(2,)))] + [(("pairs", name, j), CAMREF) for j in range(len(cams))]
    if isinstance(d.get("strobe_position_m"), list):
        out += [(("strobe_position_m",), Slot("list", length=(3,)))]
        out += [(("strobe_position_m", j), _num(-1e6, 1e6)) for j in range(3)]
    cal = d.get("calibration")
    if isinstance(cal, dict):
        out.append((("calibration",), OBJ))
        for name, mats in (cal.get("board2world") or {}).items():
            out.append((("calibration", "board2world", name), Slot("list")))
            for k in range(len(mats)):
                out.append((("calibration", "board2world", name, k), Slot("list", length=(4,))))
                out += [(("calibration", "board2world", name, k, r, c), _num(-1e6, 1e6)) for r in range(4) for c in range(4)]
        for name, cam in (cal.get("cameras") or {}).items():
            out.append((("calibration", "cameras", name), OBJ))
            if isinstance(cam.get("spots_used"), list):
                out.append((("calibration", "cameras", name, "spots_used"), Slot("list")))
                out += [(("calibration", "cameras", name, "spots_used", k), Slot("int", 0, 1e6))
                        for k in range(len(cam["spots_used"]))]
    return out


K_ROLES = {(0, 0): _num(0, 1e6, True), (1, 1): _num(0, 1e6, True), (0, 1): _num(-1e6, 1e6), (0, 2): _num(-1e6, 1e6),
           (1, 2): _num(-1e6, 1e6), (1, 0): Slot("num", exact=0.0), (2, 0): Slot("num", exact=0.0),
           (2, 1): Slot("num", exact=0.0), (2, 2): Slot("num", exact=1.0)}
#: A rotation entry: finite and bounded, and orthonormality ties it to the others; only changes
#: that no rotation allows are applied to it (NaN, huge, other types).
ROTATION = Slot("num", -1.0, 1.0, exact=None)


def rig_slots(d: dict) -> list[tuple[tuple, Slot]]:
    """The typed keys of a ``rig.json`` content (camera.py: RigFile, CameraEntry)."""
    out = [(("format",), CONST), (("cameras",), Slot("list", length=tuple(range(1, 10_000))))]
    for k, s in (("version", Slot("int", 1, 1)), ("units", CONST), ("world", TEXT)):
        if k in d:
            out.append(((k,), s))
    for i, c in enumerate(d.get("cameras", [])):
        p = ("cameras", i)
        out += [(p, OBJ), ((*p, "name"), STR), ((*p, "image_size"), Slot("list", length=(2,))),
                ((*p, "image_size", 0), Slot("int", 1, 100_000)), ((*p, "image_size", 1), Slot("int", 1, 100_000)),
                ((*p, "K"), Slot("list", length=(3,)))]
        out += [((*p, "K", r), Slot("list", length=(3,))) for r in range(3)]
        out += [((*p, "K", r, col), s) for (r, col), s in K_ROLES.items()]
        if "dist" in c:
            out += [((*p, "dist"), Slot("list", length=tuple(range(15))))]
            out += [((*p, "dist", j), _num(-1e3, 1e3)) for j in range(len(c["dist"]))]
        if "world2cam" in c:
            n = len(c["world2cam"])
            out += [((*p, "world2cam"), Slot("list", length=(3, 4)))]
            out += [((*p, "world2cam", r), Slot("list", length=(4,))) for r in range(n)]
            for r in range(n):
                for col in range(4):
                    s = ROTATION if r < 3 and col < 3 else _num(-1e9, 1e9) if r < 3 else \
                        Slot("num", exact=1.0 if col == 3 else 0.0)
                    out.append(((*p, "world2cam", r, col), s))
    return out


# --- JSON paths -------------------------------------------------------------------------------
def get(d, path):
    for k in path:
        d = d[k]
    return d


def put(d, path, value):
    get(d, path[:-1])[path[-1]] = value


def dotted(path) -> str:
    return ".".join(map(str, path))


# --- the mutations: each returns (file, key path, description), or None when it does not apply --
class Case:
    """One capture folder being mutated: its two JSON contents and its folder."""

    def __init__(self, root: Path, rng: random.Random):
        self.root, self.rng = root, rng
        self.capture = json.loads((root / "capture.json").read_text())
        self.rig = json.loads((root / self.capture.get("rig", "rig.json")).read_text())
        self.rig_file = self.capture.get("rig", "rig.json")

    def doc(self, file):
        return self.capture if file == "capture.json" else self.rig

    def slots(self):
        return [("capture.json", p, s) for p, s in capture_slots(self.capture)] + \
               [(self.rig_file, p, s) for p, s in rig_slots(self.rig)]

    def pick(self, want):
        """A random slot for which ``want(slot, value)`` holds, or None."""
        got = [(f, p, s) for f, p, s in self.slots() if want(s, get(self.doc(f), p))]
        return self.rng.choice(got) if got else None

    def used_cameras(self) -> list[str]:
        return sorted({im["camera"] for im in self.capture["images"]})

    def save(self):
        (self.root / "capture.json").write_text(json.dumps(self.capture))
        (self.root / self.rig_file).write_text(json.dumps(self.rig))


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _set_slot(case: Case, want, value_of, why: str):
    hit = case.pick(want)
    if hit is None:
        return None
    f, p, s = hit
    old = get(case.doc(f), p)
    new = value_of(s, old)
    put(case.doc(f), p, new)
    return f, dotted(p), f"{_short(old)} -> {_short(new)} ({why})"


def _short(v, n=50):
    t = json.dumps(v) if not isinstance(v, float) or math.isfinite(v) else repr(v)
    return t if len(t) <= n else t[:n - 3] + "..."


def numeric(s: Slot):
    return s.type in ("num", "int")


# Each mutation: name -> function(case) -> (file, path, description) | None. The comment says why
# the result is invalid whatever the capture.
def m_string(c):  # a number, bool, object or list slot given a string: the schema types are strict
    return _set_slot(c, lambda s, v: s.type in ("num", "int", "bool", "obj", "list"),
                     lambda s, v: c.rng.choice(["abc", str(v)[:20], ""]), "a string where a number/bool/object/list belongs")


def m_bool(c):  # true/false where no bool belongs (bools are not numbers)
    return _set_slot(c, lambda s, v: s.type != "bool", lambda s, v: c.rng.choice([True, False]), "a bool")


def m_null(c):  # null where a value is required (only truth may be null)
    return _set_slot(c, lambda s, v: not s.nullable, lambda s, v: None, "null")


def m_nan_inf(c):  # every number must be finite
    return _set_slot(c, lambda s, v: numeric(s), lambda s, v: c.rng.choice([NAN, INF, -INF]), "not finite")


def m_huge(c):  # every number has a bound far below 1e300 (the largest: 1e9, translations)
    return _set_slot(c, lambda s, v: numeric(s), lambda s, v: c.rng.choice([1e308, -1e308, 1e300, 10 ** 30]), "huge")


def m_negative(c):  # below a lower bound >= 0, or unequal to an exact 0 or 1
    return _set_slot(c, lambda s, v: numeric(s) and _is_number(v) and (s.lo >= 0 or s.exact is not None),
                     lambda s, v: -(abs(v) + 1), "negative")


def m_zero(c):  # 0 where the number must be > 0 (or exactly 1)
    return _set_slot(c, lambda s, v: numeric(s) and (s.lo > 0 or (s.lo == 0 and s.open_lo) or s.exact == 1.0),
                     lambda s, v: 0 if s.type == "int" else 0.0, "zero")


def m_fraction(c):  # a whole number given with a fraction
    return _set_slot(c, lambda s, v: s.type == "int" and _is_number(v), lambda s, v: v + 0.5, "a fraction")


def m_nested(c):  # one level too deep: a scalar in a list or an object, an object in a list, a list in a list
    def wrap(s, v):
        if s.type == "list":
            return [v]
        if s.type in ("obj", "str_or_obj"):
            return [v]
        return c.rng.choice([[v], {"value": v}])
    return _set_slot(c, lambda s, v: s.type != "list" or len(v) > 0 and s.length != (1,), wrap, "nested")


def _lengths(s: Slot, v) -> list[int]:
    return [k for k in (len(v) - 1, len(v) + 1, 0) if k >= 0 and k not in s.length]


def m_wrong_length(c):  # a list of a fixed length (K, image_size, world2cam, pairs, ...) too short or too long
    def change(s, v):
        k = c.rng.choice(_lengths(s, v))
        return v[:k] if k <= len(v) else v + [v[-1]] * (k - len(v))
    return _set_slot(c, lambda s, v: s.type == "list" and s.length and len(v) > 0 and _lengths(s, v), change,
                     "wrong length")


def m_empty_string(c):  # names, paths, kinds and formats must be non-empty strings
    return _set_slot(c, lambda s, v: s.type in ("str", "path", "camref", "const", "str_or_obj"), lambda s, v: "",
                     "empty string")


def m_missing_key(c):  # the required keys
    req = [("capture.json", ("format",)), ("capture.json", ("version",)), ("capture.json", ("kind",)),
           ("capture.json", ("images",)), (c.rig_file, ("format",)), (c.rig_file, ("cameras",))]
    req += [("capture.json", ("images", i, k)) for i in range(len(c.capture["images"])) for k in ("file", "camera")]
    req += [(c.rig_file, ("cameras", i, k)) for i in range(len(c.rig["cameras"])) for k in ("name", "K", "image_size")]
    f, p = c.rng.choice(req)
    del get(c.doc(f), p[:-1])[p[-1]]
    return f, dotted(p), "deleted (required)"


def m_delete_camera(c):  # a camera some photo was taken with leaves the rig
    name = c.rng.choice(c.used_cameras())
    i = next(i for i, cam in enumerate(c.rig["cameras"]) if cam["name"] == name)
    del c.rig["cameras"][i]
    return c.rig_file, f"cameras.{i}", f"camera {name!r} deleted (photos use it)"


def m_rename_camera(c):  # a camera some photo was taken with gets another name (unused, or another camera's)
    names = [cam["name"] for cam in c.rig["cameras"]]
    name = c.rng.choice(c.used_cameras())
    i = names.index(name)
    new = c.rng.choice([n for n in names if n != name] or ["renamed"]) if c.rng.random() < 0.5 else name + "_x"
    c.rig["cameras"][i]["name"] = new
    return c.rig_file, f"cameras.{i}.name", f"{name!r} -> {new!r} (duplicate name, or photos use the old one)"


def m_unknown_camera(c):  # an image or a pair names a camera the rig does not have
    return _set_slot(c, lambda s, v: s.type == "camref", lambda s, v: "no_such_camera", "not in the rig")


def m_unknown_version(c):  # versions are 1 (0, -1 and newer ones are refused)
    f = c.rng.choice(["capture.json", c.rig_file])
    v = c.rng.choice([0, -1, 2, 99])
    c.doc(f)["version"] = v
    return f, "version", f"{v}"


def m_unknown_kind(c):  # not a kind of capture
    v = c.rng.choice(["pitchh", "PITCH", "unknown", " hand"])
    c.capture["kind"] = v
    return "capture.json", "kind", repr(v)


def m_wrong_kind(c):  # a known kind, but not the one the command analyses (stillcap markers takes any kind)
    if c.capture_kind not in KIND_CHECKED:
        return None
    v = c.rng.choice([k for k in KINDS if k != c.capture["kind"]])
    c.capture["kind"] = v
    return "capture.json", "kind", f"{v!r} (the command reads {c.capture_kind!r})"


def m_unknown_format(c):
    f = c.rng.choice(["capture.json", c.rig_file])
    v = c.rng.choice(["stillcap-rig" if f == "capture.json" else "stillcap-capture", "x", "stillcap"])
    c.doc(f)["format"] = v
    return f, "format", repr(v)


def m_unknown_units(c):  # capture units are fixed; rig units are m, cm or mm
    if c.rng.random() < 0.5:
        c.rig["units"] = c.rng.choice(["inch", "km", "M"])
        return c.rig_file, "units", repr(c.rig["units"])
    key = c.rng.choice(["length", "time", "frequency", "angle"])
    c.capture.setdefault("units", {})[key] = c.rng.choice(["mm", "ms", "deg", "x"])
    return "capture.json", f"units.{key}", repr(c.capture["units"][key])


def m_path_escape(c):  # paths stay inside the capture folder: no absolute path, no '..', no symlink out
    hit = c.pick(lambda s, v: s.type == "path")
    f, p, _ = hit
    if c.rng.random() < 0.25:
        outside = c.root.parent / f"outside-{c.rng.randrange(10 ** 6)}.png"
        src = c.root / (get(c.doc(f), p) if p[0] == "images" else c.capture["images"][0]["file"])
        shutil.copyfile(src, outside)
        link = c.root / "images" / "link.png"
        os.symlink(outside, link)
        v = "images/link.png"
    else:
        v = c.rng.choice(["../outside.png", "/etc/passwd", "images/../../x.png", "C:/x.png", "\\\\server\\x.png",
                          "images/\x00.png"])
    put(c.doc(f), p, v)
    return f, dotted(p), repr(v)


def m_missing_file(c):  # a file the capture names does not exist
    hit = c.pick(lambda s, v: s.type == "path")
    f, p, _ = hit
    v = c.rng.choice(["images/nope.png", "nope.json", "images"])  # "images": a folder, not a file
    put(c.doc(f), p, v)
    return f, dotted(p), repr(v)


def m_unknown_image_key(c):  # image entries take only file, camera, meta and the timing keys (with their unit)
    i = c.rng.randrange(len(c.capture["images"]))
    k = c.rng.choice(["strobe", "shutter", "hz", "flashes"])
    c.capture["images"][i][k] = 80
    return "capture.json", f"images.{i}.{k}", "unknown key"


def m_bad_rotation(c):  # world2cam must be rigid: a scaled or mirrored rotation, or a last row not [0, 0, 0, 1]
    i = c.rng.randrange(len(c.rig["cameras"]))
    cam = c.rig["cameras"][i]
    T = cam.setdefault("world2cam", [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    how = c.rng.choice(["scale", "mirror", "last row"] if len(T) == 4 else ["scale", "mirror"])
    if how == "scale":  # R R^T = 1.21 I
        T[:3] = [[x * 1.1 if j < 3 else x for j, x in enumerate(row)] for row in T[:3]]
    elif how == "mirror":  # det R = -1
        T[0] = [-x if j < 3 else x for j, x in enumerate(T[0])]
    else:
        T[3] = [0.0, 0.0, 1.0, 1.0]
    return c.rig_file, f"cameras.{i}.world2cam", how


def m_bad_K_form(c):  # K is [[fx, s, cx], [0, fy, cy], [0, 0, 1]]
    i = c.rng.randrange(len(c.rig["cameras"]))
    r, col, v = c.rng.choice([(1, 0, 3.0), (2, 0, 0.5), (2, 1, -1.0), (2, 2, 2.0)])
    c.rig["cameras"][i]["K"][r][col] = v
    return c.rig_file, f"cameras.{i}.K.{r}.{col}", f"{v}"


def m_distortion_extra(c):  # only 5 coefficients are used: more than 14, or a non-zero 6th, is refused
    i = c.rng.randrange(len(c.rig["cameras"]))
    d = list(c.rig["cameras"][i].get("dist", [0.0] * 5))[:5] + [0.0] * (5 - len(c.rig["cameras"][i].get("dist", [])))
    d = d + [0.01, 0.0, 0.0] if c.rng.random() < 0.5 else d + [0.0] * 10
    c.rig["cameras"][i]["dist"] = d
    return c.rig_file, f"cameras.{i}.dist", f"{len(d)} coefficients"


# --- photo mutations ----------------------------------------------------------------------------
def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _photo(c) -> tuple[int, Path, bytes]:
    i = c.rng.randrange(len(c.capture["images"]))
    p = c.root / c.capture["images"][i]["file"]
    data = p.read_bytes()
    p.unlink()  # a hard link to the kept photo: write a new file, never into the kept one
    return i, p, data


def m_image_truncate(c):  # cut short: a PNG loses its IEND chunk, a JPEG its end-of-image marker
    i, p, data = _photo(c)
    n = int(len(data) * c.rng.uniform(0.02, 0.98))
    p.write_bytes(data[:n])
    return c.capture["images"][i]["file"], "", f"truncated to {n} of {len(data)} bytes"


def m_image_corrupt(c):  # a PNG byte changed (its chunk's CRC no longer matches), or a JPEG without its end
    i, p, data = _photo(c)
    if data[:4] == b"\x89PNG":
        k = c.rng.randrange(33, len(data) - 12)
        data = data[:k] + bytes([data[k] ^ 0x5A]) + data[k + 1:]
        what = f"byte {k} flipped"
    else:
        data = data[:data.rfind(b"\xff\xd9")]
        what = "end-of-image marker removed"
    p.write_bytes(data)
    return c.capture["images"][i]["file"], "", what


def m_image_not_image(c):  # empty, text, or garbage after a damaged signature
    i, p, data = _photo(c)
    how = c.rng.choice(["empty", "text", "garbage"])
    p.write_bytes({"empty": b"", "text": b"this is not an image\n", "garbage": b"GARBAGE!" + data[8:]}[how])
    return c.capture["images"][i]["file"], "", how


def m_image_oversize(c):  # the header claims 60000 x 60000 px (3600 megapixels, above the 100 Mpx limit)
    i, p, data = _photo(c)
    if data[:4] == b"\x89PNG":
        ihdr = struct.pack(">II", 60000, 60000) + data[24:29]
        data = data[:8] + _png_chunk(b"IHDR", ihdr) + data[33:]
    else:
        j = 2
        while not (data[j] == 0xFF and data[j + 1] in (0xC0, 0xC1, 0xC2)):
            j += 2 + int.from_bytes(data[j + 2:j + 4], "big")
        data = data[:j + 5] + struct.pack(">HH", 60000, 60000) + data[j + 9:]
    p.write_bytes(data)
    return c.capture["images"][i]["file"], "", "header claims 60000x60000"


def m_image_wrong_size(c):  # a complete photo, but not of its camera's size
    import cv2
    import numpy as np

    i, p, data = _photo(c)
    cam = next(x for x in c.rig["cameras"] if x["name"] == c.capture["images"][i]["camera"])
    w, h = cam["image_size"]
    size = c.rng.choice([(w // 2, h // 2), (w + 16, h), (max(w, h) + 8, max(w, h) + 8)])
    ok, buf = cv2.imencode(p.suffix if p.suffix.lower() in (".png", ".jpg", ".jpeg") else ".png",
                           np.zeros((size[1], size[0], 3), np.uint8))
    p.write_bytes(buf.tobytes())
    return c.capture["images"][i]["file"], "", f"{size[0]}x{size[1]} for a {w}x{h} camera"


def m_image_directory(c):  # a folder where the photo should be
    i, p, _ = _photo(c)
    p.mkdir()
    return c.capture["images"][i]["file"], "", "a folder"


MUTATIONS = {name[2:]: f for name, f in list(globals().items()) if name.startswith("m_") and callable(f)}


# --- running a case ---------------------------------------------------------------------------
def _link_tree(src: Path, dst: Path) -> None:
    """``dst`` as a copy of ``src`` whose photos are hard links (JSON files are copied)."""
    def link(s, d):
        if s.endswith(".json"):
            return shutil.copy2(s, d)
        try:
            return os.link(s, d)
        except OSError:
            return shutil.copy2(s, d)
    shutil.copytree(src, dst, copy_function=link)


@contextlib.contextmanager
def _captured_fd2():
    """stderr at the file-descriptor level (libpng's and libjpeg's messages) into a temp file."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        out = {"text": ""}
        try:
            yield out
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            out["text"] = tmp.read().decode("utf-8", "replace")


def run_command(argv: list[str]) -> dict:
    """``stillcap ARGV`` in-process: outcome, exit code, stderr lines, traceback."""
    from stillcap.cli import main

    out, err = io.StringIO(), io.StringIO()
    code, tb = 0, None
    with _captured_fd2() as fd2, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            warnings.catch_warnings():
        warnings.simplefilter("always")
        try:
            main(argv)
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else 1
        except Exception:  # noqa: BLE001 - any escape is a finding
            code, tb = None, traceback.format_exc()
    lines = [ln for ln in (err.getvalue() + fd2["text"]).splitlines() if ln.strip()]
    if tb is not None:
        outcome = "traceback"
    elif code == 0:
        outcome = "exit0"
    elif code == 2:
        outcome = "ok" if len(lines) == 1 else "lines"
    else:
        outcome = "other"
    return {"outcome": outcome, "exit": code, "stderr": lines[:20], "traceback": tb}


def campaign(captures: list[Path], cases: int, seed: int, out: Path | None = None, kinds=None, log=print) -> dict:
    """Run ``cases`` mutations over ``captures``; counts per mutation kind and outcome, and the failures."""
    rng = random.Random(seed)
    bases = []
    for cap in captures:
        kind = json.loads((Path(cap) / "capture.json").read_text()).get("kind")
        if kind in COMMANDS:
            bases.append((Path(cap), kind))
    if not bases:
        raise SystemExit("no capture of a kind the campaign runs (pitch, hand, markers, puppet)")
    names = sorted(kinds or MUTATIONS)
    counts: dict[str, Counter] = defaultdict(Counter)
    failures = []
    with tempfile.TemporaryDirectory(prefix="stillcap-mutate-") as tmp:
        n = drawn = 0
        while n < cases:
            base, kind = bases[n % len(bases)] if n < len(bases) else rng.choice(bases)
            name = rng.choice(names)
            drawn += 1
            if drawn > 20 * cases + 100:
                break
            root = Path(tmp) / f"case{drawn}" / base.name
            root.parent.mkdir()
            _link_tree(base, root)
            case = Case(root, random.Random(rng.random()))
            case.capture_kind = kind
            try:
                where = MUTATIONS[name](case)
            except Exception:  # noqa: BLE001 - a mutation that cannot apply here is drawn again later
                where = None
            if where is None:  # does not apply to this capture: not a case, drawn again
                shutil.rmtree(root.parent)
                counts[name]["n/a"] += 1
                continue
            n += 1
            if name not in ("image_truncate", "image_corrupt", "image_not_image", "image_oversize",
                            "image_wrong_size", "image_directory"):
                case.save()
            argv = [*COMMANDS[kind], str(root)]
            res = run_command(argv)
            counts[name][res["outcome"]] += 1
            if res["outcome"] != "ok":
                failures.append({"case": n, "seed": seed, "capture": str(base), "mutation": name, "file": where[0],
                                 "key": where[1], "change": where[2], "command": ["stillcap", *argv[:-1], "CAPTURE"],
                                 **res})
                log(f"case {n}: {name} {where[0]}:{where[1]} {where[2]}: {res['outcome']} "
                    f"(exit {res['exit']}) {(res['stderr'] or [''])[-1][:200]}")
            shutil.rmtree(root.parent, ignore_errors=True)
    if out is not None:
        Path(out).write_text(json.dumps(failures, indent=1, default=str) + "\n")
    return {"counts": {k: dict(v) for k, v in sorted(counts.items())}, "failures": failures}


def table(counts: dict) -> str:
    """The counts as a Markdown table (mutation kind x outcome, and the totals)."""
    cols = [*OUTCOMES, "n/a"]
    rows = ["| mutation | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
    total = Counter()
    for name, c in counts.items():
        total.update(c)
        rows.append(f"| {name} | " + " | ".join(str(c.get(k, 0)) for k in cols) + " |")
    rows.append("| **total** | " + " | ".join(f"**{total.get(k, 0)}**" for k in cols) + " |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("captures", nargs="*", type=Path, help="capture folders (default: every folder of --kept)")
    ap.add_argument("--kept", type=Path, default=Path("/tmp/kept"), help="folder of kept captures")
    ap.add_argument("--cases", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("mutate-failures.json"), help="JSON file of the failing cases")
    ap.add_argument("--only", action="append", choices=sorted(MUTATIONS), help="run only these mutations")
    a = ap.parse_args(argv)
    caps = a.captures or sorted(p for p in a.kept.iterdir() if (p / "capture.json").is_file())
    res = campaign(caps, a.cases, a.seed, a.out, a.only)
    print(table(res["counts"]))
    print(f"{len(res['failures'])} failing case(s) written to {a.out}")
    return 1 if res["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
