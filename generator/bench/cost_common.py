"""Shared by the cost benches' reports: a run's manifest entries by index, a pair's CPU seconds,
and the CPU the figures were measured on."""
import json

# The generator's own stages (conversion, writes, read-back, difficulty facts), beside the
# worker's `*_cpu_s` stages (all threads).
GENERATOR = ("convert_s", "decode_png_s", "write_s", "verify_s", "difficulty_s")


def entries(work, kind):
    return {e["index"]: e for e in map(json.loads, open("%s/%s/manifest.jsonl" % (work, kind)))}


def cpu(e):
    t = e["render_timings"]
    return sum(v for k, v in t.items() if k.endswith("_cpu_s")) + sum(t.get(k, 0.0) for k in GENERATOR)


def cpu_line():
    info = open("/proc/cpuinfo").read().splitlines()
    field = lambda name: next((l.split(":", 1)[1].strip() for l in info if l.split(":")[0].strip() == name), "?")
    cores = sum(1 for l in info if l.startswith("processor"))
    return "CPU: %s (family %s, model %s), %d cores" % (field("model name"), field("cpu family"), field("model"), cores)
