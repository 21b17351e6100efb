"""Object-space geometry from a SceneSpec `shape`: primitives, explicit meshes, strands and
leaves, and mesh files (with fallback candidates). Every shape fits the unit sphere."""

import math
import os

import bmesh
import bpy
import numpy as np
from mathutils import Quaternion, Vector


class AssetError(Exception):
    """A mesh or texture file that cannot be used; the worker reports it and moves on."""


def _normalise_bmesh(bm):
    """Scales a primitive so its farthest vertex sits on the unit sphere."""
    r = max((v.co.length for v in bm.verts), default=0.0)
    if r > 0:
        for v in bm.verts:
            v.co /= r


def _torus(bm, major_segments, minor_segments, minor_ratio):
    big = 1.0 / (1.0 + minor_ratio)
    small = big * minor_ratio
    rings = []
    for i in range(major_segments):
        u = 2.0 * math.pi * i / major_segments
        ring = []
        for j in range(minor_segments):
            v = 2.0 * math.pi * j / minor_segments
            r = big + small * math.cos(v)
            ring.append(bm.verts.new((r * math.cos(u), r * math.sin(u), small * math.sin(v))))
        rings.append(ring)
    for i in range(major_segments):
        a, b = rings[i], rings[(i + 1) % major_segments]
        for j in range(minor_segments):
            k = (j + 1) % minor_segments
            bm.faces.new((a[j], b[j], b[k], a[k]))


def canonical_mesh(name, src):
    """A copy of mesh `src` whose element order depends on its geometry only: vertices sorted by
    position, each face starting at its smallest vertex, faces sorted. (Vertices at the same
    position keep their relative order; neither the boolean solver nor bmesh's primitives make
    such duplicates.)"""
    co = [tuple(v.co) for v in src.vertices]
    order = sorted(range(len(co)), key=lambda i: co[i])
    new_index = [0] * len(co)
    for new, old in enumerate(order):
        new_index[old] = new
    faces = []
    for p in src.polygons:
        vs = [new_index[v] for v in p.vertices]
        k = vs.index(min(vs))
        faces.append((vs[k:] + vs[:k], p.material_index, p.use_smooth))
    faces.sort()
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([co[i] for i in order], [], [f[0] for f in faces])
    for m in src.materials:
        mesh.materials.append(m)
    mesh.polygons.foreach_set("material_index", [f[1] for f in faces])
    mesh.polygons.foreach_set("use_smooth", [f[2] for f in faces])
    mesh.update()
    return mesh


def _primitive(name, shape):
    kind = shape["kind"]
    bm = bmesh.new()
    r = 1.0 / math.sqrt(2.0)
    if kind == "plane":
        vs = [bm.verts.new(p) for p in ((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0))]
        bm.faces.new(vs)
    elif kind == "cube":
        bmesh.ops.create_cube(bm, size=2.0 / math.sqrt(3.0))
    elif kind == "uv_sphere":
        bmesh.ops.create_uvsphere(bm, u_segments=shape["segments"], v_segments=shape["rings"], radius=1.0)
    elif kind == "ico_sphere":
        bmesh.ops.create_icosphere(bm, subdivisions=shape["subdivisions"], radius=1.0)
    elif kind == "cylinder":
        bmesh.ops.create_cone(bm, cap_ends=True, segments=shape["vertices"], radius1=r, radius2=r, depth=2.0 * r)
    elif kind == "cone":
        bmesh.ops.create_cone(bm, cap_ends=True, segments=shape["vertices"], radius1=r, radius2=r * shape["top_ratio"], depth=2.0 * r)
    elif kind == "torus":
        _torus(bm, shape["major_segments"], shape["minor_segments"], shape["minor_ratio"])
    elif kind == "grid":
        bmesh.ops.create_grid(bm, x_segments=shape["x_segments"], y_segments=shape["y_segments"], size=1.0)
    elif kind == "monkey":
        bmesh.ops.create_monkey(bm)
    else:
        bm.free()
        raise ValueError("unknown shape kind %r" % kind)
    if kind != "plane":
        _normalise_bmesh(bm)
    built = bpy.data.meshes.new(name + "_built")
    bm.to_mesh(built)
    bm.free()
    # bmesh's UV sphere comes out with its face corners in an order that changes from process to
    # process (same vertices, other first corner): a quad's first corner picks the diagonal it is
    # split along, and subdivision sums neighbours in mesh order, so re-rendering a spec moved
    # the surface by up to 7e-4 px. In canonical order every primitive is the same in every run.
    mesh = canonical_mesh(name, built)
    bpy.data.meshes.remove(built)
    return mesh


def _strand(verts, faces, points, radii, sides):
    """A tube along a polyline; rings follow a parallel-transport frame so the tube never twists."""
    pts = [Vector(p) for p in points]
    n = len(pts)
    if n < 2:
        return
    tangents = [(pts[min(i + 1, n - 1)] - pts[max(i - 1, 0)]).normalized() for i in range(n)]
    t0 = tangents[0]
    helper = Vector((0.0, 0.0, 1.0)) if abs(t0.z) < 0.9 else Vector((1.0, 0.0, 0.0))
    normal = t0.cross(helper).normalized()
    base = len(verts)
    for i in range(n):
        if i > 0:
            axis = tangents[i - 1].cross(tangents[i])
            if axis.length > 1e-12:
                normal = Quaternion(axis.normalized(), tangents[i - 1].angle(tangents[i])) @ normal
            normal = (normal - tangents[i] * normal.dot(tangents[i])).normalized()
        binormal = tangents[i].cross(normal)
        for k in range(sides):
            a = 2.0 * math.pi * k / sides
            verts.append(pts[i] + (normal * math.cos(a) + binormal * math.sin(a)) * radii[i])
    for i in range(n - 1):
        for k in range(sides):
            k1 = (k + 1) % sides
            faces.append((base + i * sides + k, base + i * sides + k1, base + (i + 1) * sides + k1, base + (i + 1) * sides + k))
    faces.append(tuple(base + k for k in reversed(range(sides))))
    faces.append(tuple(base + (n - 1) * sides + k for k in range(sides)))


def _skeleton(name, shape):
    """Strands in material slot 0, leaf quads (with UVs for their alpha mask) in slot 1."""
    verts, faces = [], []
    for s in shape["strands"]:
        _strand(verts, faces, s["points"], s["radii"], shape["sides"])
    n_strand_faces = len(faces)
    for leaf in shape["leaves"]:
        c, u, v = Vector(leaf["center"]), Vector(leaf["u"]), Vector(leaf["v"])
        base = len(verts)
        verts.extend([c - u - v, c + u - v, c + u + v, c - u + v])
        faces.append((base, base + 1, base + 2, base + 3))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(p) for p in verts], [], faces)
    if shape["leaves"]:
        mats = [0] * n_strand_faces + [1] * (len(faces) - n_strand_faces)
        mesh.polygons.foreach_set("material_index", mats)
        uv = mesh.uv_layers.new(name="UVMap")
        corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
        coords = []
        for p in mesh.polygons:
            leaf = p.index >= n_strand_faces
            coords.extend(c for i in range(p.loop_total) for c in (corners[i % 4] if leaf else (0.0, 0.0)))
        uv.data.foreach_set("uv", coords)
    mesh.validate()
    mesh.update()
    return mesh


def _import_objects(path):
    """Runs Blender's importer for `path`; returns the new objects."""
    ext = os.path.splitext(path)[1].lower()
    before = set(bpy.data.objects)
    try:
        if ext == ".obj":
            bpy.ops.wm.obj_import(filepath=path)
        elif ext in (".glb", ".gltf"):
            bpy.ops.import_scene.gltf(filepath=path)
        elif ext == ".ply":
            bpy.ops.wm.ply_import(filepath=path)
        elif ext == ".stl":
            bpy.ops.wm.stl_import(filepath=path)
        else:
            return None
    except Exception as e:  # importers raise RuntimeError with their own message
        raise AssetError("import failed: %s" % str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__)
    return [o for o in bpy.data.objects if o not in before]


def _arrays_from_objects(objects):
    cos, tris, offset = [], [], 0
    for o in objects:
        if o.type != "MESH":
            continue
        me = o.data
        n = len(me.vertices)
        co = np.empty(n * 3, dtype=np.float64)
        me.vertices.foreach_get("co", co)
        co = co.reshape(n, 3)
        m = np.array(o.matrix_world, dtype=np.float64)
        co = co @ m[:3, :3].T + m[:3, 3]
        me.calc_loop_triangles()
        t = np.empty(len(me.loop_triangles) * 3, dtype=np.int64)
        me.loop_triangles.foreach_get("vertices", t)
        cos.append(co)
        tris.append(t.reshape(-1, 3) + offset)
        offset += n
    if not cos:
        return None, None
    return np.concatenate(cos), np.concatenate(tris)


def _remove_objects(objects):
    for o in objects:
        data = o.data
        bpy.data.objects.remove(o, do_unlink=True)
        if data is not None and getattr(data, "users", 1) == 0:
            if isinstance(data, bpy.types.Mesh):
                bpy.data.meshes.remove(data)


def _load_arrays(path):
    objects = _import_objects(path)
    if objects is None:
        try:
            import trimesh
        except ImportError:
            raise AssetError("format needs trimesh, which is not installed in this Blender Python")
        try:
            m = trimesh.load(path, force="mesh")
        except Exception as e:
            raise AssetError("trimesh cannot load it: %s" % e)
        return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    try:
        co, tris = _arrays_from_objects(objects)
    finally:
        _remove_objects(objects)
    return co, tris


def load_mesh_file(name, candidates, max_triangles, skipped):
    """The first candidate that loads, normalised to the unit sphere; failures go to `skipped`."""
    for path in candidates:
        try:
            if not os.path.isfile(path):
                raise AssetError("file not found")
            co, tris = _load_arrays(path)
            if co is None or len(co) == 0 or tris is None or len(tris) == 0:
                raise AssetError("no triangles")
            if len(tris) > max_triangles:
                raise AssetError("%d triangles is more than max_triangles = %d" % (len(tris), max_triangles))
            if not np.all(np.isfinite(co)):
                raise AssetError("non-finite vertex coordinates")
            if tris.min() < 0 or tris.max() >= len(co):
                raise AssetError("face indices out of range")
            centre = (co.min(axis=0) + co.max(axis=0)) / 2.0
            radius = float(np.linalg.norm(co - centre, axis=1).max())
            if not (radius > 1e-12 and math.isfinite(radius)):
                raise AssetError("degenerate: all vertices coincide")
            co = (co - centre) / radius
            a, b, c = co[tris[:, 0]], co[tris[:, 1]], co[tris[:, 2]]
            area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
            # A unit-sphere mesh whose faces add up to less than this draws no pixel at any size
            # we place: every vertex on a line, or all triangles collapsed.
            if not area > 1e-9:
                raise AssetError("degenerate: its triangles have zero area")
            mesh = bpy.data.meshes.new(name)
            mesh.vertices.add(len(co))
            mesh.vertices.foreach_set("co", co.astype(np.float32).ravel())
            mesh.loops.add(len(tris) * 3)
            mesh.loops.foreach_set("vertex_index", tris.astype(np.int32).ravel())
            mesh.polygons.add(len(tris))
            mesh.polygons.foreach_set("loop_start", np.arange(0, len(tris) * 3, 3, dtype=np.int32))
            mesh.update()
            mesh.validate()
            return mesh, path
        except AssetError as e:
            skipped.append({"path": path, "reason": str(e)})
    raise AssetError("none of the %d mesh candidates could be used (see skipped assets)" % len(candidates))


def make_mesh(name, shape, skipped):
    """Returns (mesh, used_path or None)."""
    kind = shape["kind"]
    if kind == "mesh":
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([tuple(v) for v in shape["vertices"]], [], [tuple(t) for t in shape["triangles"]])
        mesh.validate()
        return mesh, None
    if kind == "skeleton":
        return _skeleton(name, shape), None
    if kind == "mesh_file":
        return load_mesh_file(name, shape["candidates"], shape["max_triangles"], skipped)
    return _primitive(name, shape), None
