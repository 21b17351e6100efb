"""Builds a Blender scene from a SceneSpec: rig, geometry, materials, lights, world.

Geometry is made with bmesh (no operators, no context needed). Object-space primitives fit the
unit sphere; the spec's scale sizes them.
"""

import math

import bmesh
import bpy

import materials

SPEC_FORMAT_VERSION = 1


def reset():
    """Back to an empty factory scene, so nothing of the previous spec survives."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for block in (bpy.data.meshes, bpy.data.materials, bpy.data.images, bpy.data.lights, bpy.data.cameras):
        for item in list(block):
            block.remove(item)


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


def make_mesh(name, shape):
    kind = shape["kind"]
    mesh = bpy.data.meshes.new(name)
    if kind == "mesh":
        mesh.from_pydata([tuple(v) for v in shape["vertices"]], [], [tuple(t) for t in shape["triangles"]])
        mesh.validate()
        return mesh
    bm = bmesh.new()
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
        r = 1.0 / math.sqrt(2.0)
        bmesh.ops.create_cone(bm, cap_ends=True, segments=shape["vertices"], radius1=r, radius2=r, depth=2.0 * r)
    elif kind == "torus":
        _torus(bm, shape["major_segments"], shape["minor_segments"], shape["minor_ratio"])
    else:
        bm.free()
        raise ValueError("unknown shape kind %r" % kind)
    bm.to_mesh(mesh)
    bm.free()
    return mesh


def _add_cameras(scene, rig, render):
    cams = {}
    for view, sign in (("left", -1.0), ("right", 1.0)):
        cam = bpy.data.cameras.new("camera_" + view)
        cam.type = "PERSP"
        cam.lens_unit = "MILLIMETERS"
        cam.lens = rig["focal_mm"]
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = rig["sensor_width_mm"]
        cam.shift_x = 0.0
        cam.shift_y = 0.0
        cam.clip_start = render["clip_start"]
        cam.clip_end = render["clip_end"]
        cam.dof.use_dof = False
        ob = bpy.data.objects.new("camera_" + view, cam)
        ob.location = (sign * rig["baseline_m"] / 2.0, 0.0, 0.0)
        ob.rotation_euler = (0.0, 0.0, 0.0)
        scene.collection.objects.link(ob)
        cams[view] = ob
    return cams


def _add_light(scene, i, light):
    kind = light["kind"]
    if kind == "point":
        data = bpy.data.lights.new("light_%03d" % i, type="POINT")
        data.energy = light["power_w"]
        data.shadow_soft_size = light["radius"]
    elif kind == "sun":
        data = bpy.data.lights.new("light_%03d" % i, type="SUN")
        data.energy = light["strength"]
    else:
        raise ValueError("unknown light kind %r" % kind)
    data.color = tuple(light["color"])
    ob = bpy.data.objects.new("light_%03d" % i, data)
    if kind == "point":
        ob.location = tuple(light["location"])
    else:
        ob.rotation_euler = tuple(light["rotation"])
    scene.collection.objects.link(ob)


def _set_world(scene, world_spec):
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = tuple(world_spec["color"]) + (1.0,)
    bg.inputs["Strength"].default_value = world_spec["strength"]
    scene.world = world


def build(spec, threads, device):
    if spec.get("format_version") != SPEC_FORMAT_VERSION:
        raise ValueError("SceneSpec format_version %r is not %d" % (spec.get("format_version"), SPEC_FORMAT_VERSION))
    scene = bpy.context.scene
    import render_views
    render_views.configure(scene, spec, threads, device)
    scene["stereogen_cameras"] = ["camera_left", "camera_right"]
    _add_cameras(scene, spec["rig"], spec["render"])
    _set_world(scene, spec["world"])
    for obj in spec["objects"]:
        mesh = make_mesh(obj["name"], obj["shape"])
        mesh.materials.append(materials.make_material(obj["name"], obj["material"]))
        ob = bpy.data.objects.new(obj["name"], mesh)
        ob.location = tuple(obj["location"])
        ob.rotation_mode = "XYZ"
        ob.rotation_euler = tuple(obj["rotation"])
        ob.scale = tuple(obj["scale"])
        scene.collection.objects.link(ob)
    for i, light in enumerate(spec["lights"]):
        _add_light(scene, i, light)
    return scene
