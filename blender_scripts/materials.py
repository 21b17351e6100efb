"""Materials from MaterialSpec: flat colour (textureless) or procedural textures in object space."""

import bpy

# Which output of each texture node carries its pattern as a scalar.
_PATTERNS = {
    "noise": ("ShaderNodeTexNoise", "Fac"),
    "voronoi": ("ShaderNodeTexVoronoi", "Distance"),
    "checker": ("ShaderNodeTexChecker", "Fac"),
    "wave": ("ShaderNodeTexWave", "Fac"),
    "brick": ("ShaderNodeTexBrick", "Fac"),
    "magic": ("ShaderNodeTexMagic", "Fac"),
}


def _rgba(c):
    return (c[0], c[1], c[2], 1.0)


def make_material(name, spec):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = spec["roughness"]
    kind = spec["kind"]
    if kind == "flat":
        bsdf.inputs["Base Color"].default_value = _rgba(spec["color"])
        return mat
    if kind != "procedural":
        raise ValueError("unknown material kind %r" % kind)
    node_type, output = _PATTERNS[spec["pattern"]]
    coords = nodes.new("ShaderNodeTexCoord")
    tex = nodes.new(node_type)
    if "Scale" in tex.inputs:
        tex.inputs["Scale"].default_value = spec["scale"]
    if "Detail" in tex.inputs:
        tex.inputs["Detail"].default_value = min(spec["detail"], 15.0)
    links.new(coords.outputs["Object"], tex.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = _rgba(spec["color_a"])
    ramp.color_ramp.elements[1].color = _rgba(spec["color_b"])
    links.new(tex.outputs[output], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    return mat
