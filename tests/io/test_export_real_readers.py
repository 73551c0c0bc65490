"""Every skeleton export opened in real readers: Blender's importers (COLLADA, BVH, glTF; one
headless Blender process for all files) and assimp (``assimp dump``), joint world positions
compared with the pose; plus the real BVH files read by stillcap and by Blender."""

import sys
from pathlib import Path

import numpy as np
import pytest

from stillcap.io.bvh_read import read_bvh
from stillcap.io.export import as_export_data, export

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import (  # noqa: E402
    SHARED_DATA,
    assimp_dump,
    assimp_node_positions,
    external_tool,
    puppet_motion,
    python_module,
    run_blender,
)

TOL = 1e-4  # metres
REAL_FRAMES = [0, 1, 50, 100]  # walk01 has 101 frames at 24 fps


def _cases(tmp: Path):
    """name -> (path, reference Animation, frame indices, Blender frame offset, BVH scale)."""
    python_module("pygltflib")
    anim, _, pose = puppet_motion()
    pose_anim = as_export_data(pose).animation
    cases = {}
    for name, what, ref, opts in (
        ("pose.dae", pose, pose_anim, {}),
        ("pose_thesis.dae", pose, pose_anim, {"matrices": "translation", "skin": False}),
        ("anim.dae", anim, anim, {}),
        ("pose.bvh", pose, pose_anim, {}),
        ("anim.bvh", anim, anim, {}),
        ("anim_m.bvh", anim, anim, {"length_unit": "m"}),
        ("pose.gltf", pose, pose_anim, {}),
        ("anim.gltf", anim, anim, {}),
        ("anim.glb", anim, anim, {}),
    ):
        frames = list(range(ref.n_frames))
        cases[name] = (export(tmp / name, what, **opts), ref, frames)
    walk = SHARED_DATA / "bvh" / "walk01.bvh"
    if walk.is_file():
        real = read_bvh(walk)
        cases["walk01_original.bvh"] = (walk, real, REAL_FRAMES)
        for ext in ("bvh", "glb", "dae"):
            cases[f"walk01.{ext}"] = (export(tmp / f"walk01.{ext}", real), real, REAL_FRAMES)
    return cases


def _bvh_scale(path: Path) -> float:
    return 1.0 if path.name == "anim_m.bvh" else 0.01


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return _cases(tmp_path_factory.mktemp("readers"))


@pytest.fixture(scope="module")
def blender(cases, tmp_path_factory):
    jobs = []
    for path, ref, frames in cases.values():
        is_bvh = path.suffix == ".bvh"
        # BVH frames start at scene frame 1; COLLADA and glTF keys at frame t * 24 fps (t = k / 24).
        jobs.append({"file": str(path), "frames": [k + 1 if is_bvh else k for k in frames], "bvh_scale": _bvh_scale(path)})
    return run_blender(jobs, tmp_path_factory.mktemp("blender"))


def _compare(name, got: dict, ref, frames, rename=lambda n: n):
    names = [n for n in ref.skeleton.names if rename(n) in got]
    assert len(names) >= 19, f"{name}: reader lost joints, has {sorted(got)[:10]}..."
    g = np.array([np.asarray(got[rename(n)])[: len(frames)] for n in names]).transpose(1, 0, 2)
    r = ref.positions[frames][:, [ref.skeleton.index(n) for n in names]]
    err = np.linalg.norm(g - r, axis=-1).max()
    print(f"{name}: max joint position difference {err:.2e} m")  # shown with pytest -s (report numbers)
    assert err < TOL, f"{name}: max joint position difference {err:.3g} m"
    return err


@pytest.mark.parametrize(
    "name",
    ["pose.dae", "pose_thesis.dae", "anim.dae", "pose.bvh", "anim.bvh", "anim_m.bvh", "pose.gltf", "anim.gltf",
     "anim.glb", "walk01_original.bvh", "walk01.bvh", "walk01.glb", "walk01.dae"],
)  # fmt: skip
def test_blender_imports_joint_positions(cases, blender, name):
    if name not in cases:
        pytest.skip(f"real data {SHARED_DATA / 'bvh'} is absent")
    path, ref, frames = cases[name]
    result = blender[str(path)]
    assert "error" not in result, result.get("error")
    assert result["armatures"] == 1
    _compare(name, result["bones"], ref, frames)


@pytest.mark.parametrize(
    "name", ["pose.dae", "anim.dae", "anim.bvh", "pose.gltf", "anim.gltf", "anim.glb", "walk01.glb", "walk01.dae"]
)
def test_assimp_reads_nodes_and_positions(cases, tmp_path, name):
    external_tool("assimp", "apt-get install assimp-utils")
    if name not in cases:
        pytest.skip(f"real data {SHARED_DATA / 'bvh'} is absent")
    path, ref, frames = cases[name]
    pos, parent = assimp_node_positions(assimp_dump(path, tmp_path))
    suffix = "-joint" if path.suffix == ".dae" else ""  # assimp names COLLADA nodes by id
    scale = _bvh_scale(path) if path.suffix == ".bvh" else 1.0
    skel = ref.skeleton
    for n in skel.names:  # the hierarchy survives
        p = skel.joints[skel.index(n)].parent
        if p is not None:
            assert parent[n + suffix] == p + suffix
    n_keys = len(next(iter(pos.values())))
    keys = frames if n_keys > 1 else [0]
    scaled = {k: np.asarray(v)[keys] * scale for k, v in pos.items()}
    _compare(name, scaled, ref, frames[: len(keys)] if n_keys > 1 else frames[:1], rename=lambda n: n + suffix)
