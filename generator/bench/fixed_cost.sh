#!/usr/bin/env bash
# The fixed cost of a sample: everything of a stereo pair that is not colour rendering (worker
# start-up, scene build, depth passes, saving, the generator's PNG decode / disparity conversion /
# file writes / read-back check, manifest append), per stage, at 960x540 and at the tests' tiny size.
#
#   generator/bench/fixed_cost.sh [--bin STEREOGEN]... [--count N] [--seed S] [--sizes "960x540 64x48"]
#                                 [--pair-seconds 64.6] [--work DIR] [--keep]
#
# Each size gets a copy of the `crestereo` preset whose colour passes render 1 sample without the
# denoiser (colour then costs next to nothing and the rest shows); 64x48 is the tests' tiny recipe
# (tiny_recipe in src/lib.rs: procedural content, 2-3 objects). `stereogen generate` renders COUNT
# samples with one worker, and the medians of the manifest's `render_timings` are printed per
# stage, with the median share of a default 960x540 pair (--pair-seconds, 64.6 s measured on the
# 2-core EPYC; the colour stages are excluded from the fixed sum). Worker start-up is paid once per
# worker: it is printed apart, as is what no stage accounts for (run wall time less the stages and
# the start-up, per sample). Several --bin run one after the other per size (e.g. an old build and
# a new one), so the columns compare the same machine state, and the last row counts the samples
# whose files are byte-identical to the first build's (a scene with subdivision/displacement or
# some imported meshes can differ by ~1e-5 px from run to run, whatever the build). With
# STEREOGEN_TIMINGS_CPU=1 (set here) the worker also records the process CPU time of its stages,
# all threads (`<stage>_cpu_s`, printed in brackets): wall time misleads on a busy machine.
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
bins=()
count=8
seed=3
sizes="960x540 64x48"
pair_seconds=64.6
work=""
keep=0
while [ $# -gt 0 ]; do
    case "$1" in
        --bin) bins+=("$2"); shift 2 ;;
        --count) count=$2; shift 2 ;;
        --seed) seed=$2; shift 2 ;;
        --sizes) sizes=$2; shift 2 ;;
        --pair-seconds) pair_seconds=$2; shift 2 ;;
        --work) work=$2; shift 2 ;;
        --keep) keep=1; shift ;;
        -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
        *) echo "unknown argument $1" >&2; exit 2 ;;
    esac
done
if [ ${#bins[@]} -eq 0 ]; then
    bins=("${CARGO_TARGET_DIR:-$root/target}/release/stereogen")
fi
for b in "${bins[@]}"; do
    [ -x "$b" ] || { echo "no stereogen binary at $b (cargo build --release -p stereogen)" >&2; exit 1; }
done
if [ -z "$work" ]; then
    work=$(mktemp -d "${TMPDIR:-/tmp}/fixed-cost.XXXXXX")
fi
mkdir -p "$work"
cleanup() { if [ "$keep" = 0 ]; then rm -rf "$work"; fi; }
trap cleanup EXIT
export STEREOGEN_TIMINGS_CPU=1

# A recipe copy: the preset at WxH, colour at 1 sample, no denoiser; the tiny size as the tests
# make it.
make_recipe() {
    local w=$1 h=$2 out=$3
    python3 - "$root/crates/stereogen-plan/recipes/crestereo.toml" "$w" "$h" "$out" <<'EOF'
import re, sys
src, w, h, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
text = open(src).read()
def sub(pattern, repl, count=0):
    global text
    text, n = re.subn(pattern, repl, text, count=count, flags=re.M)
    if n == 0:
        sys.exit("recipe edit found no %r" % pattern)
sub(r"^width = .*$", "width = %d" % w)
sub(r"^height = .*$", "height = %d" % h)
sub(r"^samples = .*$", "samples = 1")
sub(r"^denoise = .*$", "denoise = false")
sub(r"^name = .*$", 'name = "fixed-cost-%dx%d"' % (w, h), count=1)
if w * h <= 128 * 96:
    # src/lib.rs tiny_recipe: procedural content, few objects, small disparities.
    sub(r"^builtin_pack = .*$", "builtin_pack = false")
    sub(r"^disparity_px = .*$", 'disparity_px = { dist = "uniform", min = 3.0, max = 20.0 }')
    sub(r"^background_disparity_px = .*$", 'background_disparity_px = { dist = "uniform", min = 0.5, max = 1.5 }')
    sub(r"^branches = .*$", "branches = [3, 4]")
    sub(r"^objects = .*$", "objects = [2, 3]")
open(out, "w").write(text)
EOF
}

results=()
for size in $sizes; do
    w=${size%x*}
    h=${size#*x}
    recipe="$work/recipe-$size.toml"
    make_recipe "$w" "$h" "$recipe"
    i=0
    for b in "${bins[@]}"; do
        out="$work/run-$size-$i"
        rm -rf "$out"
        echo "== $size, $b: $count samples (seed $seed)" >&2
        start=$(date +%s.%N)
        /usr/bin/time -f "%U %S" -o "$work/time-$size-$i" \
            "$b" generate --recipe "$recipe" --out "$out" --count "$count" --seed "$seed" \
            --workers 1 --no-progress
        end=$(date +%s.%N)
        echo "$end - $start" | bc > "$work/wall-$size-$i"
        results+=("$size|$b|$out|$work/wall-$size-$i|$work/time-$size-$i")
        i=$((i + 1))
    done
done

python3 - "$pair_seconds" "${results[@]}" <<'EOF'
import json, statistics, sys

pair = float(sys.argv[1])
runs = [r.split("|") for r in sys.argv[2:]]
ORDER = ["worker_start_s", "plan_s", "request_s", "reset_s", "build_s", "colour_left_s", "depth_left_s",
         "colour_right_s", "depth_right_s", "save_s", "decode_png_s", "convert_s", "write_s",
         "verify_s", "manifest_s"]
COLOUR = {"colour_left_s", "colour_right_s"}
ONCE = {"worker_start_s"}

def load(run):
    size, binary, out, wall_file, time_file = run
    entries = [json.loads(l) for l in open(out + "/manifest.jsonl") if l.endswith("\n")]
    wall = float(open(wall_file).read())
    user, sys_ = map(float, open(time_file).read().split()[-2:])
    return size, binary, entries, wall, user + sys_

def median(entries, key):
    vals = [e["render_timings"][key] for e in entries if key in e.get("render_timings", {})]
    return statistics.median(vals) if vals else None

for size in dict.fromkeys(r[0] for r in runs):
    loaded = [load(r) for r in runs if r[0] == size]
    keys = set()
    for _, _, entries, _, _ in loaded:
        for e in entries:
            keys.update(e.get("render_timings", {}))
    wall_keys = [k for k in ORDER if k in keys] + sorted(k for k in keys if k not in ORDER and not k.endswith("_cpu_s"))
    print()
    print("## %s: median seconds per sample (%s)" % (size, ", ".join("%d samples" % len(l[2]) for l in loaded)))
    head = "| stage |" + "".join(" %s |" % b.split("/")[-1] for _, b, _, _, _ in loaded)
    if size == "960x540":
        head += "".join(" share of a %.1f s pair |" % pair for _ in loaded)
    print(head)
    print("|" + " --- |" * (head.count("|") - 1))
    fixed = [0.0] * len(loaded)
    for k in wall_keys:
        row = "| %s%s |" % (k, " (colour, 1 spp)" if k in COLOUR else " (once per worker)" if k in ONCE else "")
        shares = ""
        for i, (_, _, entries, _, _) in enumerate(loaded):
            m = median(entries, k)
            cpu = median(entries, k[:-2] + "_cpu_s")
            row += " %s%s |" % ("—" if m is None else "%.3f" % m, "" if cpu is None else " (cpu %.3f)" % cpu)
            shares += " %s |" % ("—" if m is None or k in COLOUR or k in ONCE else "%.2f%%" % (100 * m / pair))
            if m is not None and k not in COLOUR and k not in ONCE:
                fixed[i] += m
        print(row + (shares if size == "960x540" else ""))
    row = "| unaccounted (run wall − stages − start-up, per sample) |"
    for _, _, entries, wall, _ in loaded:
        staged = sum(sum(v for k, v in e["render_timings"].items() if not k.endswith("_cpu_s") and k not in ONCE) for e in entries)
        start = sum(e["render_timings"].get("worker_start_s", 0.0) for e in entries)
        row += " %.3f |" % ((wall - staged - start) / max(1, len(entries)))
    print(row + (" |" * len(loaded) if size == "960x540" else ""))
    row = "| **fixed per sample (sum of medians, no colour, no start-up)** |"
    for f in fixed:
        row += " **%.3f** |" % f
    if size == "960x540":
        row += "".join(" **%.2f%%** |" % (100 * f / pair) for f in fixed)
    print(row)
    row = "| run: wall / CPU (user+sys, all processes) |"
    for _, _, entries, wall, cpu in loaded:
        row += " %.1f / %.1f s |" % (wall, cpu)
    print(row + (" |" * len(loaded) if size == "960x540" else ""))
    # The same (recipe, seed, index) must give the same files whichever build rendered them.
    first = {e["id"]: e["sha256"] for e in loaded[0][2]}
    row = "| samples whose files equal the first column's (sha256) |"
    for _, _, entries, _, _ in loaded:
        row += " %d of %d |" % (sum(first.get(e["id"]) == e["sha256"] for e in entries), len(entries))
    print(row + (" |" * len(loaded) if size == "960x540" else ""))
EOF
