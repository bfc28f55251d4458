"""Run inside Blender's Python (the PyPI ``bpy`` module): import USD stages and print what Blender made of them.

Usage: ``python blender_probe.py STAGE.usd [STAGE...]`` (a Python with ``bpy``). Prints one line per
stage, ``PROBE {json}``: the scene's frame range and rate, and per object its type, parent, the
evaluated world-space vertices' movement between the first and the last frame (mesh sequence caches,
armatures and shape keys applied), shape-key values per frame, signed volume (bmesh, outward
normals positive), scale per frame (markers), UV / material counts and, for a small mesh with shape
keys, its evaluated world vertices at the first and the last frame. ``tests/test_blender_import.py``
asserts on it. Not a test module itself (pytest collects ``test_*.py`` only).
"""

from __future__ import annotations

import json
import sys

import bpy


def _world_vertices(ob, depsgraph):
    ev = ob.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    pts = [tuple(ev.matrix_world @ v.co) for v in mesh.vertices]
    ev.to_mesh_clear()
    return pts


def _signed_volume(ob) -> float:
    import bmesh  # importable only once bpy is

    bm = bmesh.new()
    bm.from_mesh(ob.data)
    vol = bm.calc_volume(signed=True)
    bm.free()
    return vol


def probe(path: str) -> dict:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=path, set_frame_range=True)
    scene = bpy.context.scene
    first, last = scene.frame_start, scene.frame_end
    out = {"path": path, "frame_start": first, "frame_end": last, "fps": scene.render.fps, "objects": {}}
    meshes = [ob for ob in bpy.data.objects if ob.type == "MESH"]
    frames = list(range(first, last + 1))
    per_frame = {ob.name: [] for ob in meshes}
    keys = {ob.name: [] for ob in meshes if ob.data.shape_keys}
    scales = {ob.name: [] for ob in meshes}
    for f in frames:
        scene.frame_set(f)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        for ob in meshes:
            if f in (first, last):
                per_frame[ob.name].append(_world_vertices(ob, depsgraph))
            if ob.name in keys:
                keys[ob.name].append({kb.name: kb.value for kb in ob.data.shape_keys.key_blocks[1:]})
            scales[ob.name].append(max(abs(s) for s in ob.matrix_world.to_scale()))
    for ob in meshes:
        a, b = per_frame[ob.name][0], per_frame[ob.name][-1]
        moved = max((max(abs(p - q) for p, q in zip(u, v, strict=True)) for u, v in zip(a, b, strict=True)), default=0)
        out["objects"][ob.name] = {
            "type": ob.type,
            "parent": ob.parent.name if ob.parent else None,
            "vertices": len(ob.data.vertices),
            "moved_m": moved,
            "signed_volume_m3": _signed_volume(ob),
            "shape_keys": keys.get(ob.name),
            "scale": scales[ob.name],
            "uv_layers": len(ob.data.uv_layers),
            "materials": [m.name for m in ob.data.materials if m is not None],
            "modifiers": [m.type for m in ob.modifiers],
        }
        if ob.name in keys and len(a) <= 5000:  # a blend-shape mesh's evaluated vertices, for comparison
            out["objects"][ob.name].update(first_vertices=[list(p) for p in a], last_vertices=[list(p) for p in b])
    for ob in bpy.data.objects:
        if ob.type != "MESH":
            out["objects"][ob.name] = {"type": ob.type, "parent": ob.parent.name if ob.parent else None}
    return out


if __name__ == "__main__":
    for p in sys.argv[1:]:
        print("PROBE " + json.dumps(probe(p)), flush=True)
