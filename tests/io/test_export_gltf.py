"""glTF 2.0 export: the Khronos validator reports 0 errors; pygltflib reads back joints and skin."""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stillcap.io.export import export

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import puppet_motion, python_module, run_gltf_validator  # noqa: E402


@pytest.fixture(scope="module")
def motion():
    return puppet_motion()


@pytest.fixture(scope="module")
def files(tmp_path_factory, motion):
    python_module("pygltflib")
    anim, _, pose = motion
    d = tmp_path_factory.mktemp("gltf")
    return {n: export(d / n, what) for n, what in (("pose.gltf", pose), ("pose.glb", pose), ("anim.gltf", anim), ("anim.glb", anim))}


def test_khronos_validator_reports_no_errors(files):
    reports = run_gltf_validator(list(files.values()))
    for name in files:
        r = reports[name]
        assert r["numErrors"] == 0, r["messages"]
        assert r["numWarnings"] == 0, r["messages"]


def node_world_positions(gltf):
    n = len(gltf.nodes)
    local = []
    for node in gltf.nodes:
        m = np.eye(4)
        if node.rotation:
            m[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()
        if node.translation:
            m[:3, 3] = node.translation
        local.append(m)
    parent = {c: i for i, node in enumerate(gltf.nodes) for c in (node.children or [])}
    world = {}

    def get(i):
        if i not in world:
            world[i] = local[i] if i not in parent else get(parent[i]) @ local[i]
        return world[i]

    return {gltf.nodes[i].name: get(i)[:3, 3] for i in range(n)}


@pytest.mark.parametrize("name", ["pose.gltf", "pose.glb", "anim.gltf"])
def test_pygltflib_reads_joints_and_skin(files, motion, name):
    pg = python_module("pygltflib")
    anim, _, pose = motion
    gltf = pg.GLTF2().load(str(files[name]))
    skel = pose.skeleton
    assert len(gltf.skins) == 1 and gltf.skins[0].joints == list(range(skel.n_joints))
    assert len(gltf.meshes) == 1
    ref = pose.positions if name.startswith("pose") else anim.positions[0]
    pos = node_world_positions(gltf)
    np.testing.assert_allclose([pos[n] for n in skel.names], ref, atol=1e-7)
    if name.startswith("anim"):
        a = gltf.animations[0]
        assert len(a.channels) == skel.n_joints + 1
        assert gltf.accessors[a.samplers[0].input].count == anim.n_frames
    else:
        assert not gltf.animations
