"""Builds a Blender scene from a SceneSpec: rig, geometry with modifiers, materials, lights, world.
It obeys the spec; the only choices it makes are deterministic fallbacks for broken assets."""

import math
import os

import bpy
import numpy as np

import geometry
import materials


def reset():
    """Back to an empty factory scene, so nothing of the previous spec survives."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for block in (bpy.data.meshes, bpy.data.materials, bpy.data.images, bpy.data.lights, bpy.data.cameras, bpy.data.textures):
        for item in list(block):
            block.remove(item)


def _add_cameras(scene, cameras, render):
    """Copies the spec's camera facts (derived from the rig in Rust; nothing is re-derived here)."""
    lens = cameras["blender"]
    for view in ("left", "right"):
        cam = bpy.data.cameras.new("camera_" + view)
        cam.type = "PERSP"
        cam.lens_unit = "MILLIMETERS"
        cam.lens = lens["lens_mm"]
        cam.sensor_fit = lens["sensor_fit"]
        cam.sensor_width = lens["sensor_width_mm"]
        cam.shift_x = lens["shift_x"]
        cam.shift_y = lens["shift_y"]
        cam.clip_start = render["clip_start"]
        cam.clip_end = render["clip_end"]
        cam.dof.use_dof = False
        ob = bpy.data.objects.new("camera_" + view, cam)
        ob.location = tuple(cameras[view]["position"])
        ob.rotation_mode = "XYZ"
        ob.rotation_euler = tuple(cameras[view]["rotation"])
        scene.collection.objects.link(ob)


def _add_light(scene, i, light):
    kind = light["kind"]
    name = "light_%03d" % i
    if kind == "point":
        data = bpy.data.lights.new(name, type="POINT")
        data.energy = light["power_w"]
        data.shadow_soft_size = light["radius"]
    elif kind == "spot":
        data = bpy.data.lights.new(name, type="SPOT")
        data.energy = light["power_w"]
        data.shadow_soft_size = light["radius"]
        data.spot_size = light["spot_size"]
        data.spot_blend = light["blend"]
    elif kind == "area":
        data = bpy.data.lights.new(name, type="AREA")
        data.energy = light["power_w"]
        data.shape = "SQUARE"
        data.size = light["size"]
    elif kind == "sun":
        data = bpy.data.lights.new(name, type="SUN")
        data.energy = light["strength"]
    else:
        raise ValueError("unknown light kind %r" % kind)
    data.color = tuple(light["color"])
    ob = bpy.data.objects.new(name, data)
    if "location" in light:
        ob.location = tuple(light["location"])
    if "rotation" in light:
        ob.rotation_euler = tuple(light["rotation"])
    scene.collection.objects.link(ob)


def _set_world(scene, world_spec):
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = tuple(world_spec["color"]) + (1.0,)
    bg.inputs["Strength"].default_value = world_spec["strength"]
    sky = world_spec.get("sky")
    if sky is not None:
        # The spec's procedural sky (Hosek-Wilkie: Nishita ignores a turned lookup vector)
        # colours the background instead of the flat colour.
        tex = world.node_tree.nodes.new("ShaderNodeTexSky")
        tex.sky_type = "HOSEK_WILKIE"
        el, rot = sky["sun_elevation"], sky["sun_rotation"]
        tex.sun_direction = (math.cos(el) * math.cos(rot), math.cos(el) * math.sin(rot), math.sin(el))
        tex.turbidity = sky["turbidity"]
        tex.ground_albedo = sky["ground_albedo"]
        # The sky model's up is +Z, the rig's +Y (cameras look down -Z): turn directions by 90
        # degrees about X before the lookup, so the horizon lies ahead of the cameras.
        coords = world.node_tree.nodes.new("ShaderNodeTexCoord")
        turn = world.node_tree.nodes.new("ShaderNodeMapping")
        turn.vector_type = "VECTOR"
        turn.inputs["Rotation"].default_value = (1.5707963267948966, 0.0, 0.0)
        world.node_tree.links.new(coords.outputs["Generated"], turn.inputs["Vector"])
        world.node_tree.links.new(turn.outputs["Vector"], tex.inputs["Vector"])
        world.node_tree.links.new(tex.outputs["Color"], bg.inputs["Color"])
    hdri = world_spec.get("hdri")
    if hdri is not None:
        _add_hdri(world, bg, hdri)
    scene.world = world


def _add_hdri(world, bg, hdri):
    """One of the HDR maps Blender ships (the spec check allows only their names) around the
    scene, turned about the vertical, its radiance times the spec's strength."""
    folder = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
    path = os.path.join(folder, hdri["name"] + ".exr")
    if not os.path.isfile(path):
        raise FileNotFoundError("Blender's HDR map %s is missing (looked for %s)" % (hdri["name"], path))
    tex = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(path, check_existing=True)
    # Equirectangular maps are Z-up, the rig Y-up: a quarter turn about X, then the spec's turn
    # about the map's own vertical.
    coords = world.node_tree.nodes.new("ShaderNodeTexCoord")
    turn = world.node_tree.nodes.new("ShaderNodeMapping")
    turn.vector_type = "VECTOR"
    turn.inputs["Rotation"].default_value = (1.5707963267948966, 0.0, 0.0)
    spin = world.node_tree.nodes.new("ShaderNodeMapping")
    spin.vector_type = "VECTOR"
    spin.inputs["Rotation"].default_value = (0.0, 0.0, hdri["rotation"])
    world.node_tree.links.new(coords.outputs["Generated"], turn.inputs["Vector"])
    world.node_tree.links.new(turn.outputs["Vector"], spin.inputs["Vector"])
    world.node_tree.links.new(spin.outputs["Vector"], tex.inputs["Vector"])
    world.node_tree.links.new(tex.outputs["Color"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = hdri["strength"]


def _bake_canonical(ob):
    """Applies the object's modifiers so far and stores the result in canonical order.

    The exact boolean solver works on several threads and returns its vertices and faces in an
    order that changes from run to run. The surface is the same, but Cycles' BVH, the
    triangulation of polygons and later modifiers (subdivision sums neighbours in mesh order)
    round it differently, so re-rendering a spec was not bit-exact (disparity off by up to 5e-5
    px in a few pixels). In canonical order every later step sees the same input."""
    evaluated = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    baked = bpy.data.meshes.new_from_object(evaluated)
    mesh = geometry.canonical_mesh(ob.data.name, baked)
    bpy.data.meshes.remove(baked)
    for mod in list(ob.modifiers):
        cutter = getattr(mod, "object", None) if mod.type == "BOOLEAN" else None
        ob.modifiers.remove(mod)
        if cutter is not None:
            bpy.data.objects.remove(cutter)
    ob.data = mesh


def _add_modifiers(scene, ob, modifiers):
    for i, m in enumerate(modifiers):
        kind = m["kind"]
        name = "%s_%d_%s" % (ob.name, i, kind)
        if kind == "wireframe":
            mod = ob.modifiers.new(name, "WIREFRAME")
            mod.thickness = m["thickness"]
            mod.use_even_offset = True
            mod.use_replace = True
            mod.use_boundary = True
        elif kind == "subdivide":
            mod = ob.modifiers.new(name, "SUBSURF")
            mod.levels = m["levels"]
            mod.render_levels = m["levels"]
        elif kind == "displace":
            tex = bpy.data.textures.new(name, "CLOUDS")
            tex.noise_scale = m["noise_scale"]
            anchor = bpy.data.objects.new(name + "_anchor", None)
            anchor.location = tuple(m["offset"])
            scene.collection.objects.link(anchor)
            mod = ob.modifiers.new(name, "DISPLACE")
            mod.texture = tex
            mod.strength = m["strength"]
            mod.texture_coords = "OBJECT"
            mod.texture_coords_object = anchor
        elif kind == "boolean_cut":
            shape = {"kind": "cube"} if m["cutter"] == "cube" else {"kind": "uv_sphere", "segments": 24, "rings": 12}
            cutter_mesh, _ = geometry.make_mesh(name + "_cutter", shape, [])
            cutter = bpy.data.objects.new(name + "_cutter", cutter_mesh)
            scene.collection.objects.link(cutter)
            # Parented with an identity inverse: its transform is in the object's own space.
            cutter.parent = ob
            cutter.location = tuple(m["location"])
            cutter.rotation_euler = tuple(m["rotation"])
            cutter.scale = tuple(m["scale"])
            cutter.hide_render = True
            cutter.display_type = "WIRE"
            mod = ob.modifiers.new(name, "BOOLEAN")
            mod.operation = "DIFFERENCE"
            mod.solver = "EXACT"
            mod.object = cutter
            _bake_canonical(ob)
        elif kind == "rest_on_floor":
            _rest_on_floor(ob, m["y"])
        else:
            raise ValueError("unknown modifier kind %r" % kind)


def _rest_on_floor(ob, floor_y):
    """Moves `ob` along world Y so its lowest vertex (its mesh under its rotation and scale, before
    any Blender modifier) lies at floor_y. Its parent-free transform is location + R·S·v."""
    if ob.modifiers:
        raise ValueError("%s: rest_on_floor needs a shape without Blender modifiers" % ob.name)
    me = ob.data
    if len(me.vertices) == 0:
        return
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    rs = np.array(ob.matrix_basis, dtype=np.float64)[:3, :3]
    lowest = float((co.reshape(-1, 3).astype(np.float64) @ rs[1]).min())
    ob.location.y = floor_y - lowest


def build(spec, threads, device):
    """Builds the scene; returns (scene, skipped_assets, notes). The orchestrator checked the spec
    version once, against the worker's hello."""
    scene = bpy.context.scene
    import render_views
    render_views.configure(scene, spec, threads, device)
    _add_cameras(scene, spec["cameras"], spec["render"])
    _set_world(scene, spec["world"])
    skipped, notes = [], []
    for i, obj in enumerate(spec["objects"]):
        try:
            mesh, used = geometry.make_mesh(obj["name"], obj["shape"], skipped)
        except geometry.AssetError as e:
            # Every candidate failed: the scene goes on without this object.
            notes.append("%s dropped: %s" % (obj["name"], e))
            continue
        if used is not None:
            notes.append("%s uses %s" % (obj["name"], used))
        mesh.materials.append(materials.make_material(obj["name"], obj["material"], skipped))
        leaf = obj["shape"].get("leaf_material")
        if leaf is not None:
            mesh.materials.append(materials.make_leaf_material(obj["name"] + "_leaf", leaf, skipped))
        ob = bpy.data.objects.new(obj["name"], mesh)
        ob.location = tuple(obj["location"])
        ob.rotation_mode = "XYZ"
        ob.rotation_euler = tuple(obj["rotation"])
        ob.scale = tuple(obj["scale"])
        # Its instance id: its place in the spec, from 1 (Rust's instance table says the same).
        ob.pass_index = i + 1
        scene.collection.objects.link(ob)
        _add_modifiers(scene, ob, obj.get("modifiers", []))
    for i, light in enumerate(spec["lights"]):
        _add_light(scene, i, light)
    return scene, skipped, notes
