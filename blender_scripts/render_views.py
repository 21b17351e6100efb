"""Render settings and the renders of a stereo pair.

For each view the worker writes an 8-bit PNG (view transform Standard) and a float32 EXR with
the planar Z pass (and, where the recipe's `outputs` ask, the normal and object-index passes).
Cycles writes Z from the first sample of each pixel, which it places by importance-sampling the
pixel filter from a table: with the default 1.5 px Blackman-Harris filter that lands about 5e-4
px off the pixel centre (measured), enough for 1e-3 px errors on steep surfaces. So depth gets
its own 1-sample pass with a 0.01 px Gaussian filter (offset ~3e-6 px), and the colour pass keeps
the anti-aliasing filter of the spec. Persistent data keeps the BVH between the passes. Depth of
field, motion blur and volumes would break the Z pass and stay off.
Depth-to-disparity happens in Rust.

Both colour passes run first, then both depth passes. Z is written where a camera ray first
meets a surface that is not a cut-out (a Transparent BSDF share below `pass_alpha_threshold`):
lights, the world, bounces and the BSDFs' textures do not move it, yet a 1-sample pass spent
two thirds of its time on them (direct light at the first hit, procedural and photo textures).
So before the depth passes the scene is made depth-only, once: lights hidden, the world black,
no bounces, and every Principled BSDF replaced by a plain Diffuse BSDF; Transparent BSDFs and the
mix factors that cut leaves out stay as they are. The Z pass is bit-identical (checked on every
category) and a depth pass costs about a third. The worker's intermediate files are written
uncompressed (PNG level 0, EXR codec NONE, in the scratch folder): the generator decodes and
re-encodes them anyway, and compressing them took longer than the depth passes now do.
"""

import os
import time

import bpy


def _enable_gpu():
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for backend in ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL"):
        try:
            prefs.compute_device_type = backend
        except TypeError:
            continue
        prefs.get_devices()
        devices = [d for d in prefs.devices if d.type == backend]
        if devices:
            for d in prefs.devices:
                d.use = d.type == backend
            return backend
    raise RuntimeError("device 'gpu' requested but Cycles finds no CUDA/OptiX/HIP/oneAPI/Metal device")


def configure(scene, spec, threads, device):
    rig, render = spec["rig"], spec["render"]
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = rig["width"]
    r.resolution_y = rig["height"]
    r.resolution_percentage = 100
    r.pixel_aspect_x = 1.0
    r.pixel_aspect_y = 1.0
    r.use_motion_blur = False
    r.film_transparent = False
    r.use_border = False
    # No date, host or render-time stamps in the images (Cycles still adds its own timing
    # chunks; the generator re-encodes the PNGs without them).
    for attr in dir(r):
        if attr.startswith("use_stamp"):
            setattr(r, attr, False)
    if threads > 0:
        r.threads_mode = "FIXED"
        r.threads = threads
    c = scene.cycles
    if device == "gpu":
        _enable_gpu()
        c.device = "GPU"
    else:
        c.device = "CPU"
    c.samples = render["samples"]
    c.use_adaptive_sampling = False
    c.use_denoising = bool(render["denoise"])
    c.seed = render["cycles_seed"]
    c.use_animated_seed = False
    c.max_bounces = render["max_bounces"]
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    r.use_persistent_data = True


def _save(image, scene, path, file_format, **settings):
    """Writes the Render Result as `file_format` with the given image settings."""
    s = scene.render.image_settings
    s.file_format = file_format
    for k, v in settings.items():
        setattr(s, k, v)
    image.save_render(path, scene=scene)


# The depth pass: one sample through (very nearly) the pixel centre.
DEPTH_FILTER = ("GAUSSIAN", 0.01)

_FILTERS = {"blackman_harris": "BLACKMAN_HARRIS", "gaussian": "GAUSSIAN", "box": "BOX"}


_PREFILTERS = {"accurate": "ACCURATE", "fast": "FAST", "none": "NONE"}
_DENOISE_PASSES = {"rgb": "RGB", "albedo": "RGB_ALBEDO", "albedo_normal": "RGB_ALBEDO_NORMAL"}
_DENOISE_QUALITY = {"high": "HIGH", "balanced": "BALANCED", "fast": "FAST"}


def view_seed(render, view):
    """The Cycles seed of a view's colour pass: each view has its own (independent sensor noise);
    a spec planned before that was resolved by the orchestrator to one seed for both."""
    return render["cycles_seed_right"] if view == "right" else render["cycles_seed"]


def _colour_pass(scene, render, view="left"):
    # Every key is present: the orchestrator resolves those a spec leaves out (Rust's
    # RenderSettings::resolved), so no default is decided here.
    c = scene.cycles
    c.seed = view_seed(render, view)
    c.samples = render["samples"]
    c.use_denoising = bool(render["denoise"])
    c.denoiser = "OPENIMAGEDENOISE"
    c.denoising_prefilter = _PREFILTERS[render["denoise_prefilter"]]
    c.denoising_input_passes = _DENOISE_PASSES[render["denoise_passes"]]
    c.denoising_quality = _DENOISE_QUALITY[render["denoise_quality"]]
    threshold = render["adaptive_threshold"]  # null: adaptive sampling off
    c.use_adaptive_sampling = threshold is not None
    if threshold is not None:
        c.adaptive_threshold = threshold
        c.adaptive_min_samples = render["adaptive_min_samples"]
    c.use_light_tree = render["light_tree"]
    c.pixel_filter_type = _FILTERS[render["pixel_filter"]]
    c.filter_width = render["filter_width_px"]
    scene.view_layers[0].use_pass_z = False
    scene.view_layers[0].use_pass_material_index = False
    scene.view_layers[0].use_pass_normal = False
    scene.view_layers[0].use_pass_object_index = False


def _depth_only(scene):
    """Makes the scene depth-only, for good: nothing renders colour after it (the next request
    starts from a reset). What decides where Z is written stays: geometry, cameras, Transparent
    BSDFs and their mix factors (leaf cut-outs), materials with an Alpha below 1 (kept whole)."""
    for ob in scene.objects:
        if ob.type == "LIGHT":
            ob.hide_render = True
    if scene.world is not None and scene.world.use_nodes:
        for node in scene.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Strength"].default_value = 0.0
    scene.cycles.max_bounces = 0
    for mat in bpy.data.materials:
        if not mat.use_nodes:
            continue
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        for bsdf in [n for n in nodes if n.type == "BSDF_PRINCIPLED"]:
            alpha = bsdf.inputs["Alpha"]
            if alpha.is_linked or alpha.default_value < 1.0:
                continue
            plain = nodes.new("ShaderNodeBsdfDiffuse")
            for link in [l for l in links if l.from_node == bsdf]:
                links.new(plain.outputs[0], link.to_socket)
    scene["stereogen_depth_only"] = True


def _depth_pass(scene, outputs):
    c = scene.cycles
    c.samples = 1
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.pixel_filter_type, c.filter_width = DEPTH_FILTER
    scene.view_layers[0].use_pass_z = True
    # Where the glass and mirror pixels are (each material's pass_index at the first surface):
    # the same first hit as Z, written into the same EXR.
    scene.view_layers[0].use_pass_material_index = MATERIAL_PASS
    # The maps a recipe asks for (`outputs`), from the same first surface: Cycles writes Z, the
    # normal and the object's pass_index (its instance id, scene_builder) where the Z pass does.
    # The normal is the shading normal in world space; Rust turns it into the camera's frame.
    scene.view_layers[0].use_pass_normal = "normals" in outputs
    scene.view_layers[0].use_pass_object_index = "instance" in outputs or "semantic" in outputs
    if not scene.get("stereogen_depth_only"):
        _depth_only(scene)


# Set (by generator/bench/fixed_cost.sh): each stage also records its process CPU time, all
# threads, as `<stage>_cpu_s` (wall time misleads on a shared machine).
CPU_TIMINGS = bool(os.environ.get("STEREOGEN_TIMINGS_CPU"))
# Cleared (STEREOGEN_NO_MATERIAL_PASS=1, by generator/bench/fixed_cost.sh's comparison): the depth
# passes render without the material-index pass, whose cost the comparison measures.
MATERIAL_PASS = not os.environ.get("STEREOGEN_NO_MATERIAL_PASS")


class Timings:
    """Seconds per stage, under the names the orchestrator sent (`--timing-keys`, Rust's
    `WORKER_TIMINGS`): `seconds` is what a reply carries."""

    def __init__(self, keys):
        self.keys = keys
        self.seconds = {}

    def timed(self, key, step):
        """Runs step() and adds its wall seconds to seconds[key] (and its CPU seconds, with
        CPU_TIMINGS, under key's CPU name). Returns what step returned."""
        t0, c0 = time.perf_counter(), time.process_time()
        out = step()
        self.seconds[key] = self.seconds.get(key, 0.0) + time.perf_counter() - t0
        if CPU_TIMINGS:
            wall, cpu = self.keys["wall_suffix"], self.keys["cpu_suffix"]
            cpu_key = key[: -len(wall)] + cpu
            self.seconds[cpu_key] = self.seconds.get(cpu_key, 0.0) + time.process_time() - c0
        return out


def render_both(scene, spec, out_dir, timings):
    """Renders colour and depth of both views into out_dir: both colour passes, then both depth
    passes (after which the scene is depth-only, see the module docs). Adds to `timings` (a
    Timings): its keys' colour and depth per view, save for writing all four files."""
    keys = timings.keys
    os.makedirs(out_dir, exist_ok=True)
    files = {}
    result = lambda: bpy.data.images["Render Result"]
    camera = lambda view: setattr(scene, "camera", bpy.data.objects["camera_" + view])
    for view in ("left", "right"):
        camera(view)
        png = os.path.join(out_dir, view + ".png")
        _colour_pass(scene, spec["render"], view)
        timings.timed(keys["colour"][view], lambda: bpy.ops.render.render(write_still=False))
        timings.timed(keys["save"], lambda: _save(result(), scene, png, "PNG", color_mode="RGB", color_depth="8", compression=0))
        files[view + "_png"] = png
    for view in ("left", "right"):
        camera(view)
        exr = os.path.join(out_dir, view + "_depth.exr")
        # Counted with the depth render: the first call makes the scene depth-only.
        outputs = spec["render"]["outputs"]
        timings.timed(keys["depth"][view], lambda: (_depth_pass(scene, outputs), bpy.ops.render.render(write_still=False)))
        timings.timed(keys["save"], lambda: _save(result(), scene, exr, "OPEN_EXR_MULTILAYER", color_depth="32", exr_codec="NONE"))
        files[view + "_depth_exr"] = exr
    return files
