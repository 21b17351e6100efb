#!/usr/bin/env bash
# What the extra maps cost: the `crestereo` preset at WxH (default 960x540, its full colour
# settings) rendered once as it is and once with `outputs = ["depth", "normals", "instance",
# "semantic"]`, sample by sample in turn (sample i without maps, then with, then i+1), so both
# columns see the same machine state. Prints per sample the wall seconds of a pair
# (`render_seconds`) and the CPU seconds of its stages (STEREOGEN_TIMINGS_CPU=1: the worker's
# stages, all threads, plus the generator's conversion, writes and read-back), then the ratios of
# the sums, with the CPU model.
#
#   generator/bench/maps_cost.sh [--bin STEREOGEN] [--count N] [--seed S] [--size WxH] [--work DIR]
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
source "$here/cost_common.sh"
preset="$root/crates/stereogen-plan/recipes/crestereo.toml"
# The disparity law scales with the width (the preset's numbers are for 960 px).
python3 - "$preset" "$work" "$width" "$height" <<'EOF'
import re, sys
preset, work, w, h = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
text = open(preset).read()
text = re.sub(r"(?m)^width = \d+", "width = %d" % w, text, count=1)
text = re.sub(r"(?m)^height = \d+", "height = %d" % h, text, count=1)
scale = w / 960.0
text = text.replace("min = 2.0, max = 240.0", "min = %r, max = %r" % (2.0, 240.0 * scale))
open(work + "/plain.toml", "w").write(text.replace('name = "crestereo"', 'name = "plain"'))
maps = text.replace('name = "crestereo"', 'name = "maps"').replace(
    "[render]\n", '[render]\noutputs = ["depth", "normals", "instance", "semantic"]\n', 1)
open(work + "/maps.toml", "w").write(maps)
EOF

for ((i = 0; i < count; i++)); do
    for kind in plain maps; do
        "$bin" generate --recipe "$work/$kind.toml" --out "$work/$kind" --seed "$seed" \
            --start "$i" --count 1 --workers 1 --no-progress >/dev/null
    done
done

python3 - "$here" "$work" <<'EOF'
import sys
sys.path.insert(0, sys.argv[1])
from cost_common import cpu, cpu_line, entries
work = sys.argv[2]
plain, maps = entries(work, "plain"), entries(work, "maps")
def depth_cpu(e):
    t = e["render_timings"]
    return t.get("depth_left_cpu_s", 0.0) + t.get("depth_right_cpu_s", 0.0)
print(cpu_line())
print("%-6s %-11s %12s %12s %12s %12s %14s %14s" % ("index", "category", "wall plain", "wall maps", "cpu plain", "cpu maps", "depth cpu pl.", "depth cpu maps"))
sums = [0.0] * 6
for i in sorted(plain):
    a, b = plain[i], maps[i]
    row = [a["render_seconds"], b["render_seconds"], cpu(a), cpu(b), depth_cpu(a), depth_cpu(b)]
    sums = [s + r for s, r in zip(sums, row)]
    print("%-6d %-11s %12.2f %12.2f %12.2f %12.2f %14.2f %14.2f" % ((i, a["category"]) + tuple(row)))
print("%-18s %12.2f %12.2f %12.2f %12.2f %14.2f %14.2f" % (("sum",) + tuple(sums)))
print("maps / plain: wall %.3f, cpu %.3f (depth passes' cpu %.3f)" % (sums[1] / sums[0], sums[3] / sums[2], sums[5] / max(sums[4], 1e-9)))
EOF
