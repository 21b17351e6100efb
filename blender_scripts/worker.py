"""stereogen's Blender worker.

Runs inside Blender's Python (the `bpy` module or `blender -b --python`). Reads one JSON request
per line on stdin and answers one JSON line per request on the protocol stream (the original
stdout; everything Blender itself prints is sent to stderr). It decides nothing random: every
number it uses comes from the SceneSpec in the request.

Requests: {"cmd": "render", "spec": {...}, "out_dir": "...", "fault": "crash"|"hang"|"raise" (optional)},
{"cmd": "export_geometry", "spec": {...}, "out_dir": "..."}, {"cmd": "quit"}. Replies (field
"status"): "ready" once at start-up, with the Blender and Python versions and the SceneSpec format
version these scripts understand (the orchestrator refuses a mismatch there, once); then one "ok"
(files, timings, notes, skipped assets) or "error" (message and traceback) per render request, and
one "geometry" (the file export_geometry.py wrote, and how many renders ran meanwhile: none)
or "error" per export_geometry request. The Rust side of this protocol is `render/protocol.rs`.

A request's spec has every render key present (the orchestrator fills in the defaults of keys a
spec file leaves out), so these scripts decide no default. The worker is started with
`--threads N --device cpu|gpu --timing-keys JSON`: the last names the
stages its replies time (`WORKER_TIMINGS` in `render/protocol.rs`), so the Rust readers of those
timings and these scripts cannot disagree about a name.
"""

import json
import os
import platform
import signal
import sys
import time
import traceback

# The SceneSpec format_version these scripts read (Rust: SPEC_FORMAT_VERSION in stereogen-plan).
SPEC_FORMAT_VERSION = 3


def script_args():
    argv = sys.argv
    args = argv[argv.index("--") + 1:] if "--" in argv else argv[1:]
    opts = {"threads": 0, "device": "cpu", "timing_keys": None}
    it = iter(args)
    for a in it:
        if a == "--threads":
            opts["threads"] = int(next(it))
        elif a == "--device":
            opts["device"] = next(it)
        elif a == "--timing-keys":
            opts["timing_keys"] = json.loads(next(it))
    if opts["timing_keys"] is None:
        raise SystemExit("worker.py: --timing-keys JSON is required (the orchestrator sends it)")
    return opts


def rss_bytes():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def main():
    # Keep a private copy of stdout for the protocol, then point fd 1 at stderr so that
    # Cycles' progress lines can never interleave with a reply.
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr

    def send(obj):
        proto.write(json.dumps(obj) + "\n")
        proto.flush()

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    opts = script_args()
    import bpy  # noqa: F401  (import cost paid once per worker)
    import export_geometry
    import render_views
    import scene_builder

    # Every Cycles render this process runs, so a geometry export can prove it rendered nothing.
    renders = [0]
    bpy.app.handlers.render_pre.append(lambda *args: renders.__setitem__(0, renders[0] + 1))

    send({
        "status": "ready",
        "blender": bpy.app.version_string.split()[0],
        "python": platform.python_version(),
        "spec_format_version": SPEC_FORMAT_VERSION,
        "rss_bytes": rss_bytes(),
    })

    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        try:
            req = json.loads(line)
        except ValueError as e:
            send({"status": "error", "error": "bad request line: %s" % e})
            continue
        cmd = req.get("cmd")
        if cmd == "quit":
            break
        if cmd == "export_geometry":
            timings = render_views.Timings(opts["timing_keys"])
            send(_export_geometry(req, opts, scene_builder, export_geometry, renders, timings))
            continue
        if cmd != "render":
            send({"status": "error", "error": "unknown command %r" % cmd})
            continue

        fault = req.get("fault")
        if fault == "crash":
            os.kill(os.getpid(), signal.SIGSEGV)
        elif fault == "hang":
            while True:
                time.sleep(3600)

        keys = opts["timing_keys"]
        timings = render_views.Timings(keys)
        try:
            if fault == "raise":
                raise RuntimeError("injected failure")
            spec = req["spec"]
            timings.timed(keys["reset"], scene_builder.reset)
            scene, skipped, notes = timings.timed(
                keys["build"], lambda: scene_builder.build(spec, opts["threads"], opts["device"])
            )
            files = render_views.render_both(scene, spec, req["out_dir"], timings)
            send({"status": "ok", "files": files, "timings": timings.seconds, "rss_bytes": rss_bytes(), "skipped_assets": skipped, "notes": notes})
        except Exception as e:  # one bad spec must not take the worker down
            send({
                "status": "error",
                "error": "%s: %s" % (type(e).__name__, e),
                "traceback": traceback.format_exc(),
                "rss_bytes": rss_bytes(),
            })


def _export_geometry(req, opts, scene_builder, export_geometry, renders, timings):
    """Builds the spec as a render would, then writes its evaluated geometry instead of rendering.
    The reply counts the Cycles renders run meanwhile (`renders`): none, as the audit relies on.
    `timings` (a render_views.Timings) gets the build and export seconds."""
    keys = opts["timing_keys"]
    renders_before = renders[0]
    try:
        def build():
            scene_builder.reset()
            return scene_builder.build(req["spec"], opts["threads"], opts["device"])

        scene, skipped, notes = timings.timed(keys["build"], build)
        path, objects, triangles = timings.timed(keys["export"], lambda: export_geometry.write(scene, req["out_dir"]))
        return {
            "status": "geometry",
            "file": path,
            "objects": objects,
            "triangles": triangles,
            "renders": renders[0] - renders_before,
            "timings": timings.seconds,
            "rss_bytes": rss_bytes(),
            "skipped_assets": skipped,
            "notes": notes,
        }
    except Exception as e:
        return {"status": "error", "error": "%s: %s" % (type(e).__name__, e), "traceback": traceback.format_exc(), "rss_bytes": rss_bytes()}


if __name__ == "__main__":
    main()
