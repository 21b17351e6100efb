"""The evaluated geometry of a built scene, for `stereogen audit` (no render).

Cycles intersects the triangles of each object's evaluated mesh (modifiers applied) in world
space. This writes exactly those, per object, with what decides whether a ray stops at a hit: the
material of each triangle and, where that material cuts the surface out by a mask (leaves), the
mask's definition and the UV of each triangle corner. The Rust side casts its own rays through
them (generator/src/validate/audit/geometry.rs reads this file).

File layout (little-endian): the 8 bytes MAGIC, a u64 header length, a JSON header, then the
arrays the header points at (byte offsets from the end of the header):
  vertices           float64 (n, 3)   world space
  triangles          uint32  (m, 3)   vertex indices
  triangle_material  uint32  (m,)     index into the object's `materials`
  uv                 float64 (m, 3, 2), only when one of the object's materials has a cutout
"""

import json
import os
import struct

import bpy
import numpy as np

import materials

MAGIC = b"STGEOM01"
FORMAT_VERSION = 1
FILE_NAME = "geometry.bin"


class _Payload:
    """Appends arrays and remembers where each one starts."""

    def __init__(self):
        self.chunks, self.size = [], 0

    def add(self, array, dtype):
        data = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<")).tobytes()
        ref = {"offset": self.size, "bytes": len(data)}
        self.chunks.append(data)
        self.size += len(data)
        pad = (-self.size) % 8
        if pad:
            self.chunks.append(b"\0" * pad)
            self.size += pad
        return ref


def _cutout(material):
    text = material.get(materials.CUTOUT_PROPERTY) if material is not None else None
    return json.loads(text) if text else None


def _triangles(me):
    me.calc_loop_triangles()
    k = len(me.loop_triangles)
    tris = np.empty(k * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    mats = np.empty(k, dtype=np.int32)
    me.loop_triangles.foreach_get("material_index", mats)
    return tris.reshape(k, 3), mats


def _corner_uvs(me):
    """UV of each triangle corner, (m, 3, 2); zeros when the mesh has no UV layer."""
    k = len(me.loop_triangles)
    if me.uv_layers.active is None:
        return np.zeros((k, 3, 2))
    loops = np.empty(k * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("loops", loops)
    uv = np.empty(len(me.loops) * 2, dtype=np.float32)
    me.uv_layers.active.data.foreach_get("uv", uv)
    return uv.reshape(-1, 2)[loops].reshape(k, 3, 2).astype(np.float64)


def _object(ob, depsgraph, payload):
    ob_eval = ob.evaluated_get(depsgraph)
    me = ob_eval.to_mesh()
    try:
        n = len(me.vertices)
        co = np.empty(n * 3, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        m = np.array(ob_eval.matrix_world, dtype=np.float64)
        world = co.reshape(n, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        tris, mats = _triangles(me)
        slots = [s.material for s in ob_eval.material_slots] or [None]
        mat_info = [{"name": s.name if s is not None else None, "cutout": _cutout(s)} for s in slots]
        entry = {
            "name": ob.name,
            "vertex_count": n,
            "triangle_count": len(tris),
            "materials": mat_info,
            "vertices": payload.add(world, "f8"),
            "triangles": payload.add(tris, "u4"),
            "triangle_material": payload.add(np.clip(mats, 0, len(slots) - 1), "u4"),
            "uv": None,
        }
        if any(info["cutout"] is not None for info in mat_info):
            entry["uv"] = payload.add(_corner_uvs(me), "f8")
        return entry
    finally:
        ob_eval.to_mesh_clear()


def _camera(ob):
    cam = ob.data
    return {
        "matrix_world": [list(row) for row in ob.matrix_world],
        "lens_mm": cam.lens,
        "sensor_width_mm": cam.sensor_width,
        "sensor_fit": cam.sensor_fit,
        "shift_x": cam.shift_x,
        "shift_y": cam.shift_y,
        "clip_start": cam.clip_start,
        "clip_end": cam.clip_end,
    }


def write(scene, out_dir):
    """Writes FILE_NAME into out_dir; returns (path, object count, triangle count)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    depsgraph.update()
    payload = _Payload()
    objects = [_object(ob, depsgraph, payload) for ob in scene.objects if ob.type == "MESH" and not ob.hide_render]
    header = {
        "format_version": FORMAT_VERSION,
        "blender": bpy.app.version_string.split()[0],
        "cameras": {view: _camera(scene.objects["camera_" + view]) for view in ("left", "right")},
        "objects": objects,
    }
    head = json.dumps(header).encode("utf-8")
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, FILE_NAME)
    with open(path, "wb") as f:
        f.write(MAGIC)
        f.write(struct.pack("<Q", len(head)))
        f.write(head)
        for chunk in payload.chunks:
            f.write(chunk)
    return path, len(objects), sum(o["triangle_count"] for o in objects)
