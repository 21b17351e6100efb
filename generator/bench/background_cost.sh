#!/usr/bin/env bash
# What the backgrounds cost: the same scenes (same seed and index: the same category, rig,
# objects, materials and lights) rendered with the `crestereo` preset's textured wall, as the
# `wmgstereo` preset's room, and under its sky (each category's `background` weights set to one
# kind), sample by sample in turn so all three columns see the same machine state. At WxH
# (default 960x540, the presets' full colour settings). Prints per sample the wall seconds of a
# pair (`render_seconds`) and its CPU seconds (STEREOGEN_TIMINGS_CPU=1: the worker's stages, all
# threads, plus the generator's conversion, writes and read-back), then the ratios of the sums
# against the wall, with the CPU model.
#
#   generator/bench/background_cost.sh [--bin STEREOGEN] [--count N] [--seed S] [--size WxH] [--work DIR]
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
bin="${CARGO_TARGET_DIR:-$root/target}/release/stereogen"
count=4
seed=5
size=960x540
work=""
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bin=$2; shift 2 ;;
        --count) count=$2; shift 2 ;;
        --seed) seed=$2; shift 2 ;;
        --size) size=$2; shift 2 ;;
        --work) work=$2; shift 2 ;;
        -h|--help) sed -n '2,11p' "$0"; exit 0 ;;
        *) echo "unknown argument $1" >&2; exit 2 ;;
    esac
done
[ -x "$bin" ] || { echo "no stereogen binary at $bin (cargo build --release --workspace)" >&2; exit 1; }
if [ -z "$work" ]; then
    work=$(mktemp -d "${TMPDIR:-/tmp}/background-cost.XXXXXX")
    trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
export STEREOGEN_TIMINGS_CPU=1

width=${size%x*}
height=${size#*x}
preset="$root/crates/stereogen-plan/recipes/wmgstereo.toml"
# One recipe per background kind; the disparity law and the background disparity scale with the
# width (the preset's numbers are for 960 px).
python3 - "$preset" "$work" "$width" "$height" <<'PY'
import re, sys
preset, work, w, h = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
text = open(preset).read()
text = re.sub(r"(?m)^width = \d+", "width = %d" % w, text, count=1)
text = re.sub(r"(?m)^height = \d+", "height = %d" % h, text, count=1)
s = w / 960.0
text = text.replace("min = 2.0, max = 240.0", "min = %r, max = %r" % (2.0 * s, 240.0 * s))
text = text.replace("min = 0.4, max = 1.6", "min = %r, max = %r" % (0.4 * s, 1.6 * s))
mix = "background = { wall = 0.2, room = 0.7, environment = 0.1 }"
assert text.count(mix) == 4, "the preset's background weights changed"
for kind in ("wall", "room", "environment"):
    one = text.replace(mix, "background = { %s = 1.0 }" % kind)
    open("%s/%s.toml" % (work, kind), "w").write(one.replace('name = "wmgstereo"', 'name = "%s"' % kind, 1))
PY

kinds=(wall room environment)
for ((i = 0; i < count; i++)); do
    for kind in "${kinds[@]}"; do
        "$bin" generate --recipe "$work/$kind.toml" --out "$work/$kind" --seed "$seed" \
            --start "$i" --count 1 --workers 1 --no-progress >/dev/null
    done
done

python3 - "$work" "${kinds[@]}" <<'PY'
import json, sys
work, kinds = sys.argv[1], sys.argv[2:]
def entries(kind):
    return {e["index"]: e for e in map(json.loads, open("%s/%s/manifest.jsonl" % (work, kind)))}
runs = {k: entries(k) for k in kinds}
GENERATOR = ("convert_s", "decode_png_s", "write_s", "verify_s", "difficulty_s")
def cpu(e):
    t = e["render_timings"]
    return sum(v for k, v in t.items() if k.endswith("_cpu_s")) + sum(t.get(k, 0.0) for k in GENERATOR)
info = open("/proc/cpuinfo").read().splitlines()
field = lambda name: next((l.split(":", 1)[1].strip() for l in info if l.split(":")[0].strip() == name), "?")
print("CPU: %s (family %s, model %s), %d cores" % (field("model name"), field("cpu family"), field("model"),
                                                   sum(1 for l in info if l.startswith("processor"))))
print("%-6s %-11s" % ("index", "category") + "".join(" %12s %12s" % ("wall s " + k[:4], "cpu s " + k[:4]) for k in kinds))
sums = {k: [0.0, 0.0] for k in kinds}
for i in sorted(runs[kinds[0]]):
    row = []
    for k in kinds:
        e = runs[k][i]
        row += [e["render_seconds"], cpu(e)]
        sums[k][0] += e["render_seconds"]
        sums[k][1] += cpu(e)
    print("%-6d %-11s" % (i, runs[kinds[0]][i]["category"]) + "".join(" %12.2f" % v for v in row))
print("%-18s" % "sum" + "".join(" %12.2f %12.2f" % tuple(sums[k]) for k in kinds))
base = sums[kinds[0]]
for k in kinds[1:]:
    print("%s / %s: wall %.3f, cpu %.3f" % (k, kinds[0], sums[k][0] / base[0], sums[k][1] / base[1]))
PY
