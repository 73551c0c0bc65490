"""COLLADA export: the thesis's structure, schema validity (pycollada's 1.4.1 XSD), pycollada reads it."""

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from stillcap.io.export import export
from stillcap.io.export.collada import collada_matrices

sys.path.insert(0, str(Path(__file__).parent))  # the shared test helper beside this file
from stillcap_external_tools import puppet_motion, python_module  # noqa: E402

NS = {"c": "http://www.collada.org/2005/11/COLLADASchema"}


@pytest.fixture(scope="module")
def motion():
    return puppet_motion()


@pytest.fixture(scope="module")
def schema():
    python_module("lxml")
    schema_mod = python_module("collada.schema", "pycollada")
    return schema_mod.ColladaValidator().COLLADA_SCHEMA_1_4_1_INSTANCE  # the XSD that pycollada ships


def world_positions(path):
    """Joint positions by composing the nested <matrix> elements (the file's own semantics)."""
    root = ET.parse(path).getroot()
    out = {}

    def walk(node, parent):
        m = np.array(node.find("c:matrix", NS).text.split(), float).reshape(4, 4)
        world = parent @ m
        out[node.get("name")] = world[:3, 3]
        for child in node.findall("c:node[@type='JOINT']", NS):
            walk(child, world)

    for top in root.findall(".//c:visual_scene/c:node[@type='JOINT']", NS):
        walk(top, np.eye(4))
    return out


@pytest.mark.parametrize("options", [{}, {"matrices": "translation"}, {"skin": False}])
def test_pose_and_animation_validate_against_the_schema(tmp_path, motion, schema, options):
    lxml_etree = python_module("lxml.etree", "lxml")
    anim, _, pose = motion
    for name, what in (("pose.dae", pose), ("anim.dae", anim)):
        path = export(tmp_path / name, what, **options)
        assert schema.validate(lxml_etree.parse(str(path))), f"{name} {options}: {schema.error_log}"


def test_thesis_structure_y_up_metres_nested_joints(tmp_path, motion):
    _, _, pose = motion
    path = export(tmp_path / "pose.dae", pose)
    root = ET.parse(path).getroot()
    assert root.get("version") == "1.4.1"
    assert root.find("c:asset/c:up_axis", NS).text == "Y_UP"
    assert root.find("c:asset/c:unit", NS).get("meter") == "1"
    top = root.find("c:library_visual_scenes/c:visual_scene/c:node", NS)
    assert top.get("id") == "root-joint" and top.get("type") == "JOINT"
    children = [n.get("name") for n in top.findall("c:node", NS)]
    assert children == ["l-hip", "r-hip", "lower-back"]
    assert root.find(".//c:node[@name='l-elbow']/c:node[@name='l-hand']/c:node[@name='l-finger']", NS) is not None
    assert root.find("c:library_animations", NS) is None  # a single pose has no animation
    pos = world_positions(path)
    np.testing.assert_allclose([pos[n] for n in pose.skeleton.names], pose.positions, atol=1e-8)


def test_translation_style_is_pure_translations(tmp_path, motion):
    _, _, pose = motion
    path = export(tmp_path / "thesis.dae", pose, matrices="translation")
    for m in ET.parse(path).getroot().iter("{%s}matrix" % NS["c"]):
        np.testing.assert_allclose(np.array(m.text.split(), float).reshape(4, 4)[:3, :3], np.eye(3))
    pos = world_positions(path)
    np.testing.assert_allclose([pos[n] for n in pose.skeleton.names], pose.positions, atol=1e-8)


def test_animation_has_one_matrix_track_per_joint(tmp_path, motion):
    anim, _, _ = motion
    path = export(tmp_path / "anim.dae", anim)
    root = ET.parse(path).getroot()
    anims = root.findall("c:library_animations/c:animation", NS)
    assert len(anims) == anim.skeleton.n_joints
    first = anims[0]
    times = np.array(first.find("c:source/c:float_array", NS).text.split(), float)
    np.testing.assert_allclose(times, anim.times - anim.times[0], atol=1e-9)
    out = np.array(first.findall("c:source", NS)[1].find("c:float_array", NS).text.split(), float).reshape(-1, 4, 4)
    np.testing.assert_allclose(out, collada_matrices(anim)[:, 0], atol=1e-8)
    assert first.find("c:channel", NS).get("target") == "root-joint/transform"


def test_pycollada_reads_the_file(tmp_path, motion):
    collada = python_module("collada", "pycollada")
    anim, _, pose = motion
    c = collada.Collada(str(export(tmp_path / "anim.dae", anim)), validate_output=True)
    assert len(c.animations) == anim.skeleton.n_joints and len(c.controllers) == 1
    c = collada.Collada(str(export(tmp_path / "pose.dae", pose)))
    assert [n.id for n in c.scene.nodes][0] == "root-joint"
    np.testing.assert_allclose(c.scene.nodes[0].matrix, pose.joint2world[pose.skeleton.root], atol=1e-8)


def test_odd_joint_names_become_valid_ids(tmp_path, schema):
    lxml_etree = python_module("lxml.etree", "lxml")
    from stillcap.body import Joint, Skeleton

    skel = Skeleton((Joint("1 root", None, [0, 0, 0]), Joint("a:b", "1 root", [0, 1, 0]), Joint("a b", "1 root", [1, 0, 0])))
    path = export(tmp_path / "odd.dae", skel.rest_pose())
    assert schema.validate(lxml_etree.parse(str(path))), schema.error_log
    assert set(world_positions(path)) == {"_1_root", "a_b", "a_b_1"}
