#!/usr/bin/env python3
"""Render settings: quality against cost, measured on our own scenes (issue 29).

One command runs the study end to end and can be re-run to resume (every finished render is kept):

    python3 generator/bench/render_study.py --work ~/.cache/stereogen/render-study

Phases (each skips what is already on disk):
  prepare    plans --per-category scenes of each recipe category at --size (a copy of the recipe
             with the camera resized), renders each once with `stereogen render` for its exact
             disparity (used to match left and right pixels);
  reference  renders both colour views of every scene at 2 x --reference-samples/2 samples with
             two Cycles seeds, no denoiser, no adaptive sampling: their mean is the reference and
             their difference says how far the reference itself is from converged;
  candidates renders both views with every candidate setting (CANDIDATES below, or --candidates);
  report     PSNR and SSIM (scikit-image) of each candidate against the reference per category,
             the left/right disagreement at matched pixels, CPU and wall time per view; prints the
             table, writes results.json, results.md and pareto.png (time against error, one curve
             per category).

The render phases run inside the managed Blender Python ($STEREOGEN_PYTHON, else the newest
~/.cache/stereogen/blender/bpy-*/bin/python); the report runs in a venv with pinned numpy,
scikit-image, OpenCV, OpenEXR and matplotlib under ~/.cache/stereogen/python (made on first use).
Times are the Blender process's CPU seconds (all Cycles threads) per view — robust to other load on
the machine — beside wall seconds; both exclude the scene build, which a warm-up render pays.
"""

import argparse
import glob
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
VIEWS = ("left", "right")

# What the presets rendered with before this study: 32 samples, OpenImageDenoise with its
# accurate prefilter and albedo + normal passes, light tree on, the spec's max_bounces. Keys are
# the SceneSpec's `render` keys: a candidate goes through the generator's own colour-pass code.
BASE = {
    "samples": 32,
    "denoise": True,
    "denoise_prefilter": "accurate",
    "denoise_passes": "albedo_normal",
    "denoise_quality": "high",
    "adaptive_threshold": None,  # None: adaptive sampling off
    "adaptive_min_samples": 0,  # 0: Cycles' automatic choice
    "light_tree": True,
    "max_bounces": None,  # None: the spec's
}


def setting(**kw):
    s = dict(BASE)
    s.update(kw)
    return s


CANDIDATES = {
    # Samples alone, no denoiser.
    "s4": setting(samples=4, denoise=False),
    "s8": setting(samples=8, denoise=False),
    "s16": setting(samples=16, denoise=False),
    "s32": setting(samples=32, denoise=False),
    "s64": setting(samples=64, denoise=False),
    "s128": setting(samples=128, denoise=False),
    # Samples with the denoiser as the presets use it (s32-dn is the old default).
    "s4-dn": setting(samples=4),
    "s8-dn": setting(samples=8),
    "s16-dn": setting(samples=16),
    "s32-dn": setting(samples=32),
    "s64-dn": setting(samples=64),
    "s24-dn": setting(samples=24),
    # The denoiser's options, at 16 and 8 samples.
    "s16-dn-fast": setting(samples=16, denoise_prefilter="fast"),
    "s16-dn-albedo": setting(samples=16, denoise_passes="albedo"),
    "s16-dn-rgb": setting(samples=16, denoise_passes="rgb"),
    "s16-dn-balanced": setting(samples=16, denoise_quality="balanced"),
    "s8-dn-fast": setting(samples=8, denoise_prefilter="fast"),
    "s32-dn-fast": setting(samples=32, denoise_prefilter="fast"),
    "s32-dn-albedo": setting(samples=32, denoise_passes="albedo"),
    # Adaptive sampling (max samples, noise threshold; min samples: Cycles' automatic choice).
    "a32-t0.02-dn": setting(samples=32, adaptive_threshold=0.02),
    "a64-t0.05-dn": setting(samples=64, adaptive_threshold=0.05),
    "a64-t0.1-dn": setting(samples=64, adaptive_threshold=0.1),
    # Light tree off, fewer and more bounces.
    "s16-dn-nolt": setting(samples=16, light_tree=False),
    "s16-dn-b4": setting(samples=16, max_bounces=4),
    "s16-dn-b6": setting(samples=16, max_bounces=6),
    "s16-dn-b12": setting(samples=16, max_bounces=12),
    # Both views with the left view's Cycles seed, as specs without `cycles_seed_right` render:
    # against s16 / s32-dn, how much of the views' noise is shared.
    "s16-shared": setting(samples=16, denoise=False, shared_seed=True),
    "s32-shared": setting(samples=32, denoise=False, shared_seed=True),
    "s32-dn-shared": setting(samples=32, shared_seed=True),
}
OLD_DEFAULT = "s32-dn"
# What a plain run renders (about 25 min on 2 cores at 480x270 for 8 scenes); the rest of
# CANDIDATES are there for --candidates.
STUDY = [
    "s4", "s8", "s16", "s32", "s64",
    "s4-dn", "s8-dn", "s16-dn", "s24-dn", "s32-dn",
    "s8-dn-fast", "s16-dn-fast", "s16-dn-albedo", "s16-dn-rgb", "s32-dn-fast", "s32-dn-albedo",
    "a32-t0.02-dn", "a64-t0.05-dn",
    "s16-dn-nolt", "s16-dn-b4", "s16-dn-b6",
]


def reference_settings(samples):
    half = max(1, samples // 2)
    return {
        "ref-a": setting(samples=half, denoise=False, seed_offset=0),
        "ref-b": setting(samples=half, denoise=False, seed_offset=7919),
    }


# --------------------------------------------------------------------------------------------
# prepare (any Python)


def stereogen_bin(args):
    if args.stereogen:
        return args.stereogen
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(REPO, "target"))
    cache = os.path.expanduser("~/.cache/stereogen/target")
    for cand in (os.path.join(t, "release", "stereogen") for t in (target, cache)):
        if os.path.exists(cand):
            return cand
    if shutil.which("stereogen"):
        return shutil.which("stereogen")
    sys.exit("render_study: no stereogen binary; build it (cargo build --release) or pass --stereogen")


def recipe_text(args):
    path = args.recipe
    if not os.path.exists(path):
        path = os.path.join(REPO, "crates", "stereogen-plan", "recipes", args.recipe + ".toml")
    w, h = (int(v) for v in args.size.split("x"))
    with open(path, "rb") as f:
        width = tomllib.load(f)["camera"]["width"]
    out, section = [], None
    with open(path) as f:
        for line in f:
            s = line.strip()
            if s.startswith("["):
                section = s
            if section == "[camera]" and s.startswith("width ="):
                line = "width = %d\n" % w
            elif section == "[camera]" and s.startswith("height ="):
                line = "height = %d\n" % h
            elif section == "[placement]" and (s.startswith("disparity_px =") or s.startswith("background_disparity_px =")):
                # Same scenes as at the preset's width, only sampled more coarsely: disparities
                # scale with the image width (depth = f_px * baseline / d, and f_px scales too).
                line = re.sub(r"(min|max) = ([0-9.]+)", lambda m: "%s = %r" % (m.group(1), float(m.group(2)) * w / width), line)
            out.append(line)
    return "".join(out)


def prepare(args):
    os.makedirs(args.work, exist_ok=True)
    recipe = os.path.join(args.work, "recipe.toml")
    with open(recipe, "w") as f:
        f.write(recipe_text(args))
    sg = stereogen_bin(args)
    scenes_path = os.path.join(args.work, "scenes.json")
    if os.path.exists(scenes_path):
        with open(scenes_path) as f:
            scenes = json.load(f)
    else:
        with open(recipe, "rb") as f:
            cats = [c["name"] for c in tomllib.load(f)["categories"]]
        per_cat, scenes = {c: 0 for c in cats}, []
        for index in range(1000):
            if all(n >= args.per_category for n in per_cat.values()):
                break
            # --resolved: every render key present (the study sets them on Cycles as the worker does).
            plan = [sg, "plan", "--recipe", recipe, "--seed", str(args.seed), "--index", str(index), "--resolved"]
            spec = json.loads(subprocess.check_output(plan))
            cat = spec["category"]
            if per_cat.get(cat, 0) < args.per_category:
                per_cat[cat] += 1
                path = os.path.join(args.work, "specs", "%s_%s.json" % (cat, spec["id"]))
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with open(path, "w") as f:
                    json.dump(spec, f)
                scenes.append({"category": cat, "id": spec["id"], "spec": path})
        scenes.sort(key=lambda s: (s["category"], s["id"]))
        with open(scenes_path, "w") as f:
            json.dump(scenes, f, indent=1)
    for s in scenes:
        base = os.path.join(args.work, "base")
        disp = os.path.join(base, s["category"], s["id"] + "_left.disp.exr")
        if not os.path.exists(disp):
            print("prepare: ground truth of %s/%s" % (s["category"], s["id"]), flush=True)
            subprocess.check_call([sg, "render", "--spec", s["spec"], "--out", base])
    return scenes


# --------------------------------------------------------------------------------------------
# render (inside Blender's Python)


def apply(scene, spec, st, view):
    import render_views

    render = dict(spec["render"])
    render.update((k, v) for k, v in st.items() if k not in ("seed_offset", "max_bounces", "shared_seed"))
    render_views._colour_pass(scene, render, view)
    c = scene.cycles
    seed = render_views.view_seed(spec["render"], "left" if st.get("shared_seed") else view)
    c.seed = (seed + st.get("seed_offset", 0)) % (2**31)
    c.max_bounces = st["max_bounces"] if st["max_bounces"] is not None else spec["render"]["max_bounces"]


def render_phase(args, settings):
    sys.path.insert(0, os.path.join(REPO, "blender_scripts"))
    import bpy
    import render_views
    import scene_builder

    with open(os.path.join(args.work, "scenes.json")) as f:
        scenes = json.load(f)
    times_path = os.path.join(args.work, "times.jsonl")
    for s in scenes:
        todo = [
            (name, view)
            for name in settings
            for view in VIEWS
            if not os.path.exists(os.path.join(args.work, "renders", name, s["category"], "%s_%s.png" % (s["id"], view)))
        ]
        if not todo:
            continue
        with open(s["spec"]) as f:
            spec = json.load(f)
        scene_builder.reset()
        scene, _, _ = scene_builder.build(spec, args.threads, "cpu")
        scene.render.image_settings.color_depth = "16"
        # Warm-up: BVH and shader compilation, so that no candidate pays for them.
        scene.camera = bpy.data.objects["camera_left"]
        apply(scene, spec, setting(samples=1, denoise=False), "left")
        bpy.ops.render.render(write_still=False)
        for name, view in todo:
            st = settings[name]
            scene.camera = bpy.data.objects["camera_" + view]
            apply(scene, spec, st, view)
            c0, w0 = time.process_time(), time.perf_counter()
            bpy.ops.render.render(write_still=False)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            out = os.path.join(args.work, "renders", name, s["category"], "%s_%s.png" % (s["id"], view))
            os.makedirs(os.path.dirname(out), exist_ok=True)
            tmp = out + ".tmp.png"
            render_views._save(bpy.data.images["Render Result"], scene, tmp, "PNG", color_mode="RGB", color_depth="16", compression=15)
            os.replace(tmp, out)
            with open(times_path, "a") as f:
                f.write(json.dumps({"setting": name, "category": s["category"], "id": s["id"], "view": view, "cpu_s": cpu, "wall_s": wall}) + "\n")
            print("render: %-16s %s/%s %-5s cpu %.2f s wall %.2f s" % (name, s["category"], s["id"], view, cpu, wall), flush=True)


def blender_python():
    p = os.environ.get("STEREOGEN_PYTHON")
    if p:
        return p
    home = os.environ.get("STEREOGEN_HOME", os.path.expanduser("~/.cache/stereogen"))
    found = sorted(glob.glob(os.path.join(home, "blender", "bpy-*", "bin", "python")))
    if not found:
        sys.exit("render_study: no managed Blender Python; run `stereogen setup` or set STEREOGEN_PYTHON")
    return found[-1]


# --------------------------------------------------------------------------------------------
# report (in the study venv)

PINS = ["numpy==2.4.6", "scikit-image==0.26.0", "opencv-python-headless==5.0.0.93", "OpenEXR==3.5.3", "matplotlib==3.11.2"]


def study_python():
    home = os.environ.get("STEREOGEN_HOME", os.path.expanduser("~/.cache/stereogen"))
    venv = os.path.join(home, "python", "venv-render-study-" + "-".join(p.replace("==", "") for p in PINS))
    py = os.path.join(venv, "bin", "python")
    if not os.path.exists(py):
        tmp = venv + ".partial"
        shutil.rmtree(tmp, ignore_errors=True)
        subprocess.check_call([sys.executable, "-m", "venv", tmp])
        subprocess.check_call([os.path.join(tmp, "bin", "python"), "-m", "pip", "install", "-q", *PINS])
        os.rename(tmp, venv)
    return py


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", required=True, help="study folder (keep it outside the repository)")
    ap.add_argument("--phase", default="all", choices=["all", "prepare", "reference", "candidates", "report"])
    ap.add_argument("--recipe", default="crestereo", help="preset name or recipe TOML [crestereo]")
    ap.add_argument("--size", default="480x270", help="WIDTHxHEIGHT of the study renders [480x270]")
    ap.add_argument("--per-category", type=int, default=2, help="scenes per recipe category [2]")
    ap.add_argument("--seed", type=int, default=0, help="dataset seed of the planned scenes [0]")
    ap.add_argument("--reference-samples", type=int, default=512, help="samples of the reference, split over two seeds [512]")
    ap.add_argument("--candidates", default=None, help="comma list of candidate names [%s; also known: %s]" % (",".join(STUDY), ",".join(n for n in CANDIDATES if n not in STUDY)))
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads [0: all cores]")
    ap.add_argument("--stereogen", default=None, help="the stereogen binary [$CARGO_TARGET_DIR/release/stereogen]")
    ap.add_argument("--in-blender", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--in-venv", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.work = os.path.abspath(os.path.expanduser(args.work))
    names = args.candidates.split(",") if args.candidates else list(STUDY)
    unknown = [n for n in names if n not in CANDIDATES]
    if unknown:
        sys.exit("render_study: unknown candidate(s) %s; known: %s" % (", ".join(unknown), ", ".join(CANDIDATES)))
    refs = reference_settings(args.reference_samples)

    if args.in_blender:
        settings = refs if args.phase == "reference" else {n: CANDIDATES[n] for n in names}
        render_phase(args, settings)
        return
    if args.in_venv:
        import render_study_report

        render_study_report.report(args, names, refs, CANDIDATES, OLD_DEFAULT)
        return

    forward, skip = [], False
    for a in sys.argv[1:]:
        if skip:
            skip = False
        elif a == "--phase":
            skip = True
        elif not a.startswith("--phase="):
            forward.append(a)
    if args.phase in ("all", "prepare"):
        prepare(args)
    for phase in ("reference", "candidates"):
        if args.phase in ("all", phase):
            subprocess.check_call([blender_python(), os.path.abspath(__file__), *forward, "--phase", phase, "--in-blender"])
    if args.phase in ("all", "report"):
        env = dict(os.environ, PYTHONPATH=HERE, OPENCV_IO_ENABLE_OPENEXR="1")
        subprocess.check_call([study_python(), os.path.abspath(__file__), *forward, "--phase", "report", "--in-venv"], env=env)


if __name__ == "__main__":
    main()
