"""COLLADA 1.4.1 (.dae) export: the thesis's nested ``<node type="JOINT">`` skeleton.

Each joint is a node holding one 4x4 ``<matrix sid="transform">`` (row-major text, metres,
``<unit meter="1">``, ``<up_axis>Y_UP</up_axis>``) nested under ``<library_visual_scenes>``
as in the thesis (section 6.3). Two matrix styles:

- ``matrices="local"`` (default): each matrix is the joint in its parent's frame,
  ``T(offset) @ R_local`` (the root: ``root2world @ R_root``); orientations (twist) survive;
- ``matrices="translation"``: the thesis's own style, pure translations by the posed bone
  vector in world axes (joint frames stay parallel to the world; orientations are dropped).

An Animation adds ``<library_animations>`` with one matrix (float4x4) track per joint, LINEAR,
times in seconds from the first frame. With ``skin=True`` (default) a small stick-figure mesh
is bound to the joints by a ``<controller><skin>`` so that viewers show the skeleton; its bind
pose is the rest pose for an animation and the exported pose itself for a single pose.

Node ``name`` and ``sid`` are the joint name (ids add ``-joint``, as in the thesis); the schema
types them as XML NCNames, so other characters (spaces, colons, a leading digit) become ``_``.

Written with the standard library's ``xml.etree``: pycollada (read and validate) cannot write
``type="JOINT"`` nodes or animations, so the XML is built by hand; the tests validate every
file against the COLLADA 1.4.1 schema that pycollada ships.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from stillcap.files.atomic import write_bytes
from stillcap.io.export._base import ExportData, register, stick_mesh

__all__ = ["write_collada", "collada_matrices"]

NS = "http://www.collada.org/2005/11/COLLADASchema"


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def _ncname(name: str) -> str:
    """A valid XML NCName (COLLADA ids and sids) from any joint name."""
    s = re.sub(r"[^A-Za-z0-9_.\-]", "_", name)
    return s if re.match(r"[A-Za-z_]", s) else "_" + s


def _unique(names):
    seen: dict[str, int] = {}
    out = []
    for n in names:
        k = seen.get(n, 0)
        seen[n] = k + 1
        out.append(n if k == 0 else f"{n}_{k}")
    return out


def collada_matrices(animation, matrices: str = "local") -> np.ndarray:
    """The per-joint node matrices written to COLLADA.

    Parameters
    ----------
    animation : Animation
    matrices : {"local", "translation"}

    Returns
    -------
    ndarray, shape (n_frames, n_joints, 4, 4)
        Each joint's transform in its parent node's frame.
    """
    skel = animation.skeleton
    j2w = animation.joint2world
    parents = skel.parents
    out = np.empty_like(j2w)
    if matrices == "local":
        for j in range(skel.n_joints):
            p = parents[j]
            out[:, j] = j2w[:, j] if p < 0 else np.linalg.inv(j2w[:, p]) @ j2w[:, j]
    elif matrices == "translation":
        pos = j2w[..., :3, 3]
        out[:] = np.eye(4)
        for j in range(skel.n_joints):
            p = parents[j]
            out[:, j, :3, 3] = pos[:, j] if p < 0 else pos[:, j] - pos[:, p]
    else:
        raise ValueError(f"matrices must be 'local' or 'translation', got {matrices!r}")
    return out


def _source_floats(parent, sid: str, values, stride: int, params) -> None:
    src = ET.SubElement(parent, "source", id=sid)
    values = np.ravel(values)
    arr = ET.SubElement(src, "float_array", id=f"{sid}-array", count=str(values.size))
    arr.text = _fmt(values)
    tc = ET.SubElement(src, "technique_common")
    acc = ET.SubElement(tc, "accessor", source=f"#{sid}-array", count=str(values.size // stride), stride=str(stride))
    for name, typ in params:
        ET.SubElement(acc, "param", name=name, type=typ)


def _source_names(parent, sid: str, names, param: str) -> None:
    src = ET.SubElement(parent, "source", id=sid)
    arr = ET.SubElement(src, "Name_array", id=f"{sid}-array", count=str(len(names)))
    arr.text = " ".join(names)
    tc = ET.SubElement(src, "technique_common")
    acc = ET.SubElement(tc, "accessor", source=f"#{sid}-array", count=str(len(names)), stride="1")
    ET.SubElement(acc, "param", name=param, type="name")


@register(".dae")
def write_collada(
    path, data: ExportData, matrices: str = "local", skin: bool = True, scene_name: str | None = None
) -> Path:
    """Write a pose or animation as COLLADA 1.4.1.

    Parameters
    ----------
    path : str or PathLike
    data : ExportData
        Needs a pose or animation (markers are not written).
    matrices : {"local", "translation"}
        Node matrix style (see the module docstring).
    skin : bool
        Add a stick-figure mesh skinned to the joints.
    scene_name : str, optional
        Name of the visual scene (default: the skeleton's name).

    Returns
    -------
    Path
    """
    anim = data.require_motion("COLLADA")
    skel = anim.skeleton
    mats = collada_matrices(anim, matrices)
    ids = _unique([_ncname(n) + "-joint" for n in skel.names])
    sids = _unique([_ncname(n) for n in skel.names])
    root = ET.Element("COLLADA", xmlns=NS, version="1.4.1")
    asset = ET.SubElement(root, "asset")
    contrib = ET.SubElement(asset, "contributor")
    ET.SubElement(contrib, "authoring_tool").text = "stillcap"
    now = datetime.now(timezone.utc).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    ET.SubElement(asset, "created").text = now
    ET.SubElement(asset, "modified").text = now
    ET.SubElement(asset, "unit", name="meter", meter="1")
    ET.SubElement(asset, "up_axis").text = "Y_UP"

    if not data.single_pose:
        lib = ET.SubElement(root, "library_animations")
        times = anim.times - anim.times[0]
        for j in range(skel.n_joints):
            aid = f"{ids[j]}-anim"
            a = ET.SubElement(lib, "animation", id=aid)
            _source_floats(a, f"{aid}-input", times, 1, [("TIME", "float")])
            _source_floats(a, f"{aid}-output", mats[:, j], 16, [("TRANSFORM", "float4x4")])
            _source_names(a, f"{aid}-interpolation", ["LINEAR"] * len(times), "INTERPOLATION")
            sampler = ET.SubElement(a, "sampler", id=f"{aid}-sampler")
            for sem, suffix in (("INPUT", "input"), ("OUTPUT", "output"), ("INTERPOLATION", "interpolation")):
                ET.SubElement(sampler, "input", semantic=sem, source=f"#{aid}-{suffix}")
            ET.SubElement(a, "channel", source=f"#{aid}-sampler", target=f"{ids[j]}/transform")

    if skin:
        # Bind pose: the rest pose for an animation; the pose itself for a single pose (Blender
        # shows an unanimated skinned armature in its bind pose, not at the node matrices).
        bind = anim.joint2world[0] if data.single_pose else skel.rest_pose().joint2world
        verts, tris, vjoint = stick_mesh(skel, bind)
        geoms = ET.SubElement(root, "library_geometries")
        geom = ET.SubElement(geoms, "geometry", id="stick-figure-mesh", name="stick-figure")
        mesh = ET.SubElement(geom, "mesh")
        _source_floats(mesh, "stick-figure-positions", verts, 3, [("X", "float"), ("Y", "float"), ("Z", "float")])
        vtx = ET.SubElement(mesh, "vertices", id="stick-figure-vertices")
        ET.SubElement(vtx, "input", semantic="POSITION", source="#stick-figure-positions")
        tri = ET.SubElement(mesh, "triangles", count=str(len(tris)))
        ET.SubElement(tri, "input", semantic="VERTEX", source="#stick-figure-vertices", offset="0")
        ET.SubElement(tri, "p").text = " ".join(str(int(i)) for i in tris.ravel())

        ctrls = ET.SubElement(root, "library_controllers")
        ctrl = ET.SubElement(ctrls, "controller", id="stick-figure-skin", name="stick-figure-skin")
        sk = ET.SubElement(ctrl, "skin", source="#stick-figure-mesh")
        ET.SubElement(sk, "bind_shape_matrix").text = _fmt(np.eye(4))
        _source_names(sk, "stick-figure-joints", sids, "JOINT")
        _source_floats(sk, "stick-figure-bind-poses", np.linalg.inv(bind), 16, [("TRANSFORM", "float4x4")])
        _source_floats(sk, "stick-figure-weights", [1.0], 1, [("WEIGHT", "float")])
        joints_el = ET.SubElement(sk, "joints")
        ET.SubElement(joints_el, "input", semantic="JOINT", source="#stick-figure-joints")
        ET.SubElement(joints_el, "input", semantic="INV_BIND_MATRIX", source="#stick-figure-bind-poses")
        vw = ET.SubElement(sk, "vertex_weights", count=str(len(verts)))
        ET.SubElement(vw, "input", semantic="JOINT", source="#stick-figure-joints", offset="0")
        ET.SubElement(vw, "input", semantic="WEIGHT", source="#stick-figure-weights", offset="1")
        ET.SubElement(vw, "vcount").text = " ".join("1" for _ in vjoint)
        ET.SubElement(vw, "v").text = " ".join(f"{int(j)} 0" for j in vjoint)

    scenes = ET.SubElement(root, "library_visual_scenes")
    vs_id = _ncname(scene_name or skel.name)
    vs = ET.SubElement(scenes, "visual_scene", id=vs_id, name=vs_id)
    nodes = {}
    for j in skel.depth_first:
        p = skel.parents[j]
        parent_el = vs if p < 0 else nodes[p]
        node = ET.SubElement(parent_el, "node", id=ids[j], name=sids[j], sid=sids[j], type="JOINT")
        ET.SubElement(node, "matrix", sid="transform").text = _fmt(mats[0, j])
        nodes[j] = node
    if skin:
        mnode = ET.SubElement(vs, "node", id="stick-figure", name="stick-figure", type="NODE")
        ic = ET.SubElement(mnode, "instance_controller", url="#stick-figure-skin")
        ET.SubElement(ic, "skeleton").text = f"#{ids[skel.root]}"
    scene = ET.SubElement(root, "scene")
    ET.SubElement(scene, "instance_visual_scene", url=f"#{vs_id}")

    ET.indent(root, space=" ")
    xml = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return write_bytes(path, xml + b"\n")
