# Sourced by the cost benches (maps_cost.sh, background_cost.sh): their common options
# [--bin STEREOGEN] [--count N] [--seed S] [--size WxH] [--work DIR], the binary check, the work
# folder (a temporary one, removed at exit, unless --work names one) and per-stage CPU timings.
# Sets bin, count, seed, width, height, work; `-h` prints the sourcing script's header.
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
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
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
        *) echo "unknown argument $1" >&2; exit 2 ;;
    esac
done
[ -x "$bin" ] || { echo "no stereogen binary at $bin (cargo build --release --workspace)" >&2; exit 1; }
if [ -z "$work" ]; then
    work=$(mktemp -d "${TMPDIR:-/tmp}/$(basename "$0" .sh).XXXXXX")
    trap 'rm -rf "$work"' EXIT
fi
mkdir -p "$work"
export STEREOGEN_TIMINGS_CPU=1
width=${size%x*}
height=${size#*x}
