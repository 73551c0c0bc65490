"""Helpers for tests that use external programs and real data (Blender, assimp, the Khronos glTF
validator, optional Python packages, ../shared/data).

A missing tool skips the test on a developer's machine but FAILS it when the environment
variable ``CI`` is set, because CI installs every tool (see docs/exports.md).
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

REPO = Path(__file__).resolve().parents[2]
PROBE = Path(__file__).with_name("blender_probe.py")
VALIDATOR_DIR = REPO / "tools" / "gltf-validator"
SHARED_DATA = REPO.parent / "shared" / "data"


def missing(what: str, how: str) -> None:
    """Skip locally, fail under CI: ``what`` is not available; ``how`` says how to install it."""
    msg = f"{what} is not available ({how})"
    if os.environ.get("CI"):
        pytest.fail(msg + " - CI must install it")
    pytest.skip(msg)


def external_tool(name: str, how: str) -> str:
    """Path of an executable, or skip/fail (:func:`missing`)."""
    path = shutil.which(name)
    if path is None:
        missing(f"the program {name!r}", how)
    return path


def python_module(name: str, pip_name: str | None = None):
    """Import an optional module, or skip/fail (:func:`missing`)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        missing(f"the Python package {pip_name or name!r}", f"pip install {pip_name or name}")


def shared_data(sub: str) -> Path:
    """A folder of ../shared/data; skip (also under CI) when it is absent, as data/README.md says."""
    path = SHARED_DATA / sub
    if not path.is_dir():
        pytest.skip(f"real data folder {path} is absent")
    return path


# -- Blender ----------------------------------------------------------------------------------
def run_blender(jobs: list[dict], workdir: Path) -> dict[str, dict]:
    """Import files in ONE headless Blender process; bone-head world positions (y up) per job.

    Each job: ``{"file": str, "frames": [int], "bvh_scale": float}``. Returns file -> result.
    """
    blender = external_tool("blender", "apt-get install blender python3-numpy")
    jobs_path, out_path = workdir / "blender_jobs.json", workdir / "blender_out.json"
    jobs_path.write_text(json.dumps(jobs))
    proc = subprocess.run(
        [blender, "-b", "--factory-startup", "--python", str(PROBE), "--", str(jobs_path), str(out_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if not out_path.exists():
        raise AssertionError(f"Blender failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return {r["file"]: r for r in json.loads(out_path.read_text())}


# -- glTF validator ---------------------------------------------------------------------------
def run_gltf_validator(files: list[Path]) -> dict[str, dict]:
    """Khronos glTF validator reports (file -> report with numErrors, messages)."""
    node = external_tool("node", "Node.js ships with the machine image; apt-get install nodejs")
    if not (VALIDATOR_DIR / "node_modules" / "gltf-validator").is_dir():
        missing("the npm package gltf-validator", f"cd {VALIDATOR_DIR} && npm ci")
    proc = subprocess.run(
        [node, str(VALIDATOR_DIR / "validate.js")] + [str(f) for f in files], capture_output=True, text=True, timeout=120
    )
    if proc.returncode not in (0, 1):
        raise AssertionError(f"glTF validator failed: {proc.stderr}")
    return {Path(r["file"]).name: r for r in json.loads(proc.stdout)}


# -- assimp -----------------------------------------------------------------------------------
def assimp_dump(path: Path, workdir: Path) -> Path:
    """``assimp dump FILE OUT.assxml`` (assimp's XML scene dump); the dump's path."""
    assimp = external_tool("assimp", "apt-get install assimp-utils")
    out = workdir / (path.name + ".assxml")
    proc = subprocess.run([assimp, "dump", str(path), str(out)], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0 or not out.exists():
        raise AssertionError(f"assimp dump {path.name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    return out


def _floats(el) -> np.ndarray:
    return np.array(el.text.split(), float)


def assimp_node_positions(dump: Path) -> tuple[dict[str, np.ndarray], dict[str, str | None]]:
    """World positions of every node in an assimp XML dump, per animation key.

    Animated nodes use their position / rotation / scaling keys (key k, or key 0 of a
    constant track); other nodes their matrix. Returns (name -> (n_keys, 3), name -> parent).
    """
    root = ET.parse(dump).getroot()
    scene = root.find("Scene")
    local: dict[str, np.ndarray] = {}
    parent: dict[str, str | None] = {}

    def walk(node, par):
        name = node.get("name")
        local[name] = _floats(node.find("Matrix4")).reshape(4, 4)
        parent[name] = par
        lst = node.find("NodeList")
        for child in [] if lst is None else lst.findall("Node"):
            walk(child, name)

    walk(scene.find("Node"), None)
    tracks: dict[str, dict[str, np.ndarray]] = {}
    anim = scene.find("AnimationList/Animation")
    n_keys = 1
    if anim is not None:
        for na in anim.iter("NodeAnim"):
            t = {}
            for kind, tag in (("pos", "PositionKey"), ("rot", "RotationKey"), ("scale", "ScalingKey")):
                keys = [_floats(k) for k in na.iter(tag)]
                if keys:
                    t[kind] = np.array(keys)
                    n_keys = max(n_keys, len(keys))
            tracks[na.get("node")] = t

    def local_at(name: str, k: int) -> np.ndarray:
        if name not in tracks:
            return local[name]
        t = tracks[name]
        m = np.eye(4)
        rot = t.get("rot")
        scale = t.get("scale")
        pos = t.get("pos")
        r = np.eye(3) if rot is None else Rotation.from_quat(rot[min(k, len(rot) - 1)]).as_matrix()  # x y z w
        s = np.ones(3) if scale is None else scale[min(k, len(scale) - 1)]
        m[:3, :3] = r * s
        m[:3, 3] = local[name][:3, 3] if pos is None else pos[min(k, len(pos) - 1)]
        return m

    out = {}
    for k in range(n_keys):
        world: dict[str, np.ndarray] = {}

        def get(name):
            if name not in world:
                p = parent[name]
                world[name] = local_at(name, k) if p is None else get(p) @ local_at(name, k)
            return world[name]

        for name in local:
            out.setdefault(name, []).append(get(name)[:3, 3])
    return {k: np.array(v) for k, v in out.items()}, parent


# -- test data ----------------------------------------------------------------------------------
def puppet_motion(n_frames: int = 5, seed: int = 0, fps: float = 24.0):
    """A puppet animation (random joint rotations, root turning and moving), its markers with
    some unseen (NaN), and its middle pose. Times are k / fps, so Blender frames are exact."""
    from stillcap.body import Animation, MarkerSet, Skeleton

    skel, ms = Skeleton.puppet(), MarkerSet.puppet()
    rng = np.random.default_rng(seed)
    local = Rotation.from_rotvec(rng.normal(scale=0.4, size=(n_frames * skel.n_joints, 3))).as_matrix()
    local = local.reshape(n_frames, skel.n_joints, 3, 3)
    r2w = np.tile(skel.rest_root2world(), (n_frames, 1, 1))
    r2w[:, :3, :3] = Rotation.from_euler("y", np.linspace(0, 150, n_frames)[:, None], degrees=True).as_matrix()
    r2w[:, :3, 3] += np.linspace(0, 0.05, n_frames)[:, None]
    anim = Animation(skel, np.arange(n_frames) / fps, r2w, local)
    markers = ms.trajectories(anim)
    markers.points[1, 3] = np.nan
    markers.points[2, :5] = np.nan
    return anim, markers, anim[n_frames // 2]
