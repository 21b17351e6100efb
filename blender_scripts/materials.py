"""Principled BSDF materials from a MaterialSpec: flat, procedural or photo base colour, with the
roughness / metallic / transmission / IOR the spec gives; and the alpha-cut leaf material."""

import json
import os

import bpy

# The leaf mask as data: opaque where (u - cu)^2 + (v - cv)^2 < radius^2 in the quad's UV square.
# Stored on the leaf material (CUTOUT_PROPERTY) so `stereogen audit` decides hits by the same rule.
LEAF_CUTOUT = {"kind": "uv_disc", "centre": [0.5, 0.5], "radius": 0.5}
CUTOUT_PROPERTY = "stereogen_cutout"

# Which output of each texture node carries its pattern as a scalar.
_PATTERNS = {
    "noise": ("ShaderNodeTexNoise", "Fac"),
    "voronoi": ("ShaderNodeTexVoronoi", "Distance"),
    "checker": ("ShaderNodeTexChecker", "Fac"),
    "wave": ("ShaderNodeTexWave", "Fac"),
    "brick": ("ShaderNodeTexBrick", "Fac"),
    "magic": ("ShaderNodeTexMagic", "Fac"),
    "gradient": ("ShaderNodeTexGradient", "Fac"),
}


def _rgba(c):
    return (c[0], c[1], c[2], 1.0)


def _input(node, *names):
    for n in names:
        if n in node.inputs:
            return node.inputs[n]
    raise KeyError("%s has none of the inputs %s" % (node.bl_idname, names))


def _object_coords(nodes, links, scale, rotation=0.0, stretch=None):
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    stretch = stretch or (1.0, 1.0, 1.0)
    mapping.inputs["Scale"].default_value = tuple(scale * s for s in stretch)
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, rotation)
    links.new(coords.outputs["Object"], mapping.inputs["Vector"])
    return mapping.outputs["Vector"]


def _downsampled(image, longer_side):
    """The planner's mip level of a strongly minified photo: Cycles samples image textures
    without mipmaps, so the copy is what keeps fine detail from aliasing into moire."""
    if not longer_side:
        return image
    w, h = image.size
    if max(w, h) <= longer_side:
        return image
    name = "%s@%d" % (image.name, longer_side)
    if name in bpy.data.images:
        return bpy.data.images[name]
    f = longer_side / max(w, h)
    small = image.copy()
    small.name = name
    small.scale(max(1, round(w * f)), max(1, round(h * f)))
    return small


def _base_color(nodes, links, bsdf, base, skipped):
    kind = base["kind"]
    target = bsdf.inputs["Base Color"]
    if kind == "flat":
        target.default_value = _rgba(base["color"])
    elif kind == "procedural":
        node_type, output = _PATTERNS[base["pattern"]]
        tex = nodes.new(node_type)
        if "Scale" in tex.inputs:
            tex.inputs["Scale"].default_value = 1.0
        if "Detail" in tex.inputs:
            tex.inputs["Detail"].default_value = min(base["detail"], 15.0)
        links.new(_object_coords(nodes, links, base["scale"]), tex.inputs["Vector"])
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = _rgba(base["color_a"])
        ramp.color_ramp.elements[1].color = _rgba(base["color_b"])
        links.new(tex.outputs[output], ramp.inputs["Fac"])
        links.new(ramp.outputs["Color"], target)
    elif kind == "image":
        path = base["path"]
        try:
            if not os.path.isfile(path):
                raise RuntimeError("file not found")
            image = bpy.data.images.load(path, check_existing=True)
            if image.size[0] == 0 or image.size[1] == 0:
                raise RuntimeError("image has no pixels")
            # A photo is colour data: decode it as sRGB whatever the file or the defaults say.
            image.colorspace_settings.name = "sRGB"
            image = _downsampled(image, base.get("texture_px"))
        except RuntimeError as e:
            skipped.append({"path": path, "reason": "texture cannot be loaded: %s" % e})
            target.default_value = _rgba(base["fallback"])
            return
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = image
        # Box projection in object space textures meshes that have no UVs.
        tex.projection = "BOX"
        tex.projection_blend = 0.2
        tex.extension = "REPEAT"
        coords = _object_coords(nodes, links, base["scale"], base["rotation"], base.get("stretch"))
        links.new(coords, tex.inputs["Vector"])
        links.new(tex.outputs["Color"], target)
    else:
        raise ValueError("unknown base colour kind %r" % kind)


def make_material(name, spec, skipped):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    _base_color(nodes, links, bsdf, spec["base"], skipped)
    bsdf.inputs["Roughness"].default_value = spec["roughness"]
    bsdf.inputs["Metallic"].default_value = spec["metallic"]
    _input(bsdf, "Transmission Weight", "Transmission").default_value = spec["transmission"]
    bsdf.inputs["IOR"].default_value = spec["ior"]
    # Read back from the material-index pass as the sample's glass and mirror pixels.
    mat.pass_index = spec.get("pass_index", 0)
    return mat


def make_leaf_material(name, spec, skipped):
    """A leaf: the spec's surface inside an ellipse of the quad's UV square, fully transparent
    outside. The mask is exactly 0 or 1 (a comparison, no blur), so the depth pass stays
    deterministic: cut-out pixels show whatever is behind the leaf."""
    mat = make_material(name, spec, skipped)
    mat[CUTOUT_PROPERTY] = json.dumps(LEAF_CUTOUT)
    centre, radius = LEAF_CUTOUT["centre"], LEAF_CUTOUT["radius"]
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    out = nodes["Material Output"]
    uv = nodes.new("ShaderNodeTexCoord")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(uv.outputs["UV"], sep.inputs["Vector"])

    def centred_square(axis, c):
        sub = nodes.new("ShaderNodeMath")
        sub.operation = "SUBTRACT"
        sub.inputs[1].default_value = c
        links.new(sep.outputs[axis], sub.inputs[0])
        sq = nodes.new("ShaderNodeMath")
        sq.operation = "MULTIPLY"
        links.new(sub.outputs[0], sq.inputs[0])
        links.new(sub.outputs[0], sq.inputs[1])
        return sq.outputs[0]

    add = nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    links.new(centred_square("X", centre[0]), add.inputs[0])
    links.new(centred_square("Y", centre[1]), add.inputs[1])
    inside = nodes.new("ShaderNodeMath")
    inside.operation = "LESS_THAN"
    inside.inputs[1].default_value = radius * radius
    links.new(add.outputs[0], inside.inputs[0])
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(inside.outputs[0], mix.inputs["Fac"])
    links.new(transparent.outputs[0], mix.inputs[1])
    links.new(bsdf.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    return mat
