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
  normals            float64 (m, 3, 3) world-space unit normal at each triangle corner, the one
                     Cycles interpolates on a smooth-shaded triangle
  triangle_smooth    uint32  (m,)     1 where Cycles shades the triangle smooth (interpolated
                     corner normals), 0 where it uses the triangle's own geometric normal
Each object also says whether its transform mirrors (`negative_scale`): Cycles turns a mirrored
object's geometric normal round so it stays on the side of the shading normals.
"""

import json
import os
import struct

import bpy
import numpy as np

import materials

MAGIC = b"STGEOM01"
# 2: corner normals and smooth flags per triangle (the audit of normal maps).
FORMAT_VERSION = 2
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


def _bools(me, name, domain_size):
    """A boolean attribute as an array (all False when the mesh has none)."""
    attr = me.attributes.get(name)
    out = np.zeros(domain_size, dtype=bool)
    if attr is not None and attr.data_type == "BOOLEAN":
        attr.data.foreach_get("value", out)
    return out


def _cycles_shading(me):
    """How Cycles 4.x shades the triangles (intern/cycles/blender/mesh.cc, create_mesh): the domain
    is `Mesh::normals_domain(support_sharp_face=true)`, which the Python property does not give
    (it answers for support_sharp_face=false). Returns (smooth per triangle, corner normals in
    object space per triangle corner, (m, 3, 3)).

    - custom normals, or some but not all edges sharp: face-corner domain. Cycles splits the
      mesh along the corner normals and shades every triangle smooth with them.
    - every face sharp, or every edge sharp: face domain. Every triangle flat.
    - otherwise (the usual case, sharp faces mixed with smooth ones allowed): point domain. Smooth
      faces interpolate the vertex normals, sharp ones are flat."""
    k = len(me.loop_triangles)
    loops = np.empty(k * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("loops", loops)
    verts = np.empty(k * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("vertices", verts)
    tri_smooth = np.empty(k, dtype=bool)
    me.loop_triangles.foreach_get("use_smooth", tri_smooth)
    sharp_face = _bools(me, "sharp_face", len(me.polygons))
    sharp_edge = _bools(me, "sharp_edge", len(me.edges))
    if me.has_custom_normals:
        domain = me.normals_domain
    elif len(me.polygons) and sharp_face.all():
        domain = "FACE"
    elif len(me.edges) and sharp_edge.all():
        domain = "FACE"
    elif not sharp_edge.any():
        domain = "POINT"
    else:
        domain = "CORNER"
    if domain == "CORNER":
        normals = np.empty(len(me.corner_normals) * 3, dtype=np.float32)
        me.corner_normals.foreach_get("vector", normals)
        corner = normals.reshape(-1, 3)[loops]
        smooth = np.ones(k, dtype=bool)
    else:
        normals = np.empty(len(me.vertex_normals) * 3, dtype=np.float32)
        me.vertex_normals.foreach_get("vector", normals)
        corner = normals.reshape(-1, 3)[verts]
        smooth = tri_smooth if domain == "POINT" else np.zeros(k, dtype=bool)
    return smooth, corner.astype(np.float64).reshape(k, 3, 3)


def _world_normals(corner, m):
    """Object-space normals to world space by the normal matrix (the inverse transpose of the
    3x3 part), normalised as Cycles does when it applies an object's transform to its mesh."""
    k = corner.shape[0]
    # Row vectors: n @ (M^-T)^T = n @ M^-1.
    world = corner.reshape(-1, 3) @ np.linalg.inv(m[:3, :3])
    length = np.linalg.norm(world, axis=1, keepdims=True)
    world = np.where(length > 0, world / np.where(length > 0, length, 1), 0)
    return world.reshape(k, 3, 3)


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
        smooth, corner = _cycles_shading(me)
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
            "normals": payload.add(_world_normals(corner, m), "f8"),
            "triangle_smooth": payload.add(smooth, "u4"),
            "negative_scale": bool(np.linalg.det(m[:3, :3]) < 0),
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
