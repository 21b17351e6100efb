#!/usr/bin/env bash
# What the backgrounds cost: the same scenes (same seed and index: the same category, rig,
# objects, materials and lights) rendered with the `crestereo` preset's textured wall, as the
# `wmgstereo` preset's room, and as its environment (sky or HDR map; each category's `background` weights set to one
# kind), sample by sample in turn so all three columns see the same machine state. At WxH
# (default 960x540, the presets' full colour settings). Prints per sample the wall seconds of a
# pair (`render_seconds`) and its CPU seconds (STEREOGEN_TIMINGS_CPU=1: the worker's stages, all
# threads, plus the generator's conversion, writes and read-back), then the ratios of the sums
# against the wall, with the CPU model.
#
#   generator/bench/background_cost.sh [--bin STEREOGEN] [--count N] [--seed S] [--size WxH] [--work DIR]
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
source "$here/cost_common.sh"
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

python3 - "$here" "$work" "${kinds[@]}" <<'PY'
import sys
sys.path.insert(0, sys.argv[1])
from cost_common import cpu, cpu_line, entries
work, kinds = sys.argv[2], sys.argv[3:]
runs = {k: entries(work, k) for k in kinds}
print(cpu_line())
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
