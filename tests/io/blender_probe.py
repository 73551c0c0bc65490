"""Run inside Blender (``blender -b --factory-startup --python blender_probe.py -- JOBS.json OUT.json``).

Imports each file of the job list with Blender's own importer (COLLADA, BVH, glTF) and writes
the world positions of every armature bone head, converted back to y-up (x, y, z), for the
requested scene frames. A job: ``{"file": path, "frames": [int, ...], "bvh_scale": float}``.
Blender 3.4 on Python 3.11 needs two shims, applied here and not to system files: the BVH
importer opens files with mode 'rU' (removed in Python 3.11) and the glTF importer uses
``numpy.bool`` (removed in NumPy 1.24).
"""

import builtins
import json
import sys
import traceback

import bpy
import numpy

if not hasattr(numpy, "bool"):
    numpy.bool = bool  # glTF importer shim


def _open_without_u(file, mode="r", *args, **kwargs):
    return builtins.open(file, mode.replace("U", ""), *args, **kwargs)


def _clear():
    for coll in (bpy.data.objects, bpy.data.armatures, bpy.data.meshes, bpy.data.actions, bpy.data.materials):
        for item in list(coll):
            coll.remove(item)


def _import(path, bvh_scale):
    low = path.lower()
    if low.endswith(".dae"):
        bpy.ops.wm.collada_import(filepath=path)
    elif low.endswith(".bvh"):
        import io_anim_bvh.import_bvh as ib

        ib.open = _open_without_u  # 'rU' shim, module-local
        bpy.ops.import_anim.bvh(filepath=path, global_scale=bvh_scale, use_fps_scale=False, update_scene_duration=True)
    elif low.endswith((".gltf", ".glb")):
        bpy.ops.import_scene.gltf(filepath=path)
    else:
        raise ValueError(f"unknown format: {path}")


def _heads(frames):
    scene = bpy.context.scene
    out = {}
    arms = [o for o in scene.objects if o.type == "ARMATURE"]
    for f in frames:
        scene.frame_set(f)
        bpy.context.view_layer.update()
        for arm in arms:
            for pb in arm.pose.bones:
                p = arm.matrix_world @ pb.head
                out.setdefault(pb.name, []).append([p.x, p.z, -p.y])  # Blender z-up -> y-up
    return out, len(arms)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :]
    jobs = json.load(open(argv[0]))
    results = []
    for job in jobs:
        _clear()
        try:
            _import(job["file"], job.get("bvh_scale", 1.0))
            bones, n_arm = _heads(job.get("frames") or [bpy.context.scene.frame_current])
            results.append({"file": job["file"], "bones": bones, "armatures": n_arm,
                            "fps": bpy.context.scene.render.fps,
                            "frame_range": [bpy.context.scene.frame_start, bpy.context.scene.frame_end]})
        except Exception:
            results.append({"file": job["file"], "error": traceback.format_exc()})
    with open(argv[1], "w") as f:
        json.dump(results, f)


main()
