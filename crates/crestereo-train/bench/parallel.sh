#!/usr/bin/env bash
# Data-parallel training on one CPU machine: time per training step of
#   A) one process, batch B, T threads               (the baseline)
#   B) two processes on the loopback, batch B/2 each, T/2 threads each
# on the same data and config, interleaved, and the all-reduce's share of B's step (the
# replicas' gradients: 5,432,948 floats, 21.7 MB per step). Prints the CPU it ran on.
#
#   parallel.sh [CRESTEREO_BIN] [OUT_DIR]
#
# SIZE (env, default 384x512 = the paper's crop), BATCH (2), ITERS (10), STEPS (4: the first is
# not counted), THREADS (2), ROUNDS (2: A and B alternate this many times).
set -euo pipefail
BIN=${1:-${CARGO_TARGET_DIR:-target}/release/crestereo}
OUT=${2:-$(mktemp -d)}
SIZE=${SIZE:-384x512}
BATCH=${BATCH:-2}
ITERS=${ITERS:-10}
STEPS=${STEPS:-4}
THREADS=${THREADS:-2}
ROUNDS=${ROUNDS:-2}
H=${SIZE%x*}
W=${SIZE#*x}
mkdir -p "$OUT"
echo "CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) cores," \
  "$(grep -m1 -o -w 'avx512f' /proc/cpuinfo || echo no-avx512)," \
  "$(grep -m1 -o -w 'avx2' /proc/cpuinfo || echo no-avx2)"
echo "step: batch $BATCH at ${SIZE}, $ITERS iterations, $STEPS steps (first not counted), $THREADS threads in all"
"$BIN" synth --out "$OUT/data" --count 16 --size "$((H + 16))x$((W + 16))" >/dev/null 2>&1
cat >"$OUT/train.toml" <<EOF
steps = $STEPS
batch_size = $BATCH
accumulate = 1
iters = $ITERS
[[datasets]]
path = "$OUT/data"
[augment]
crop = [$H, $W]
[schedule]
warmup_steps = 1
decay_start = $STEPS
[loader]
workers = 1
[log]
every = 1
[checkpoint]
every = $STEPS
EOF
# Median seconds per step after the first, from a run's train_log.csv (elapsed_s is column 7).
per_step() {
  awk -F, 'NR>2 { d = $7 - prev; print d } NR>1 { prev = $7 }' "$1/train_log.csv" |
    sort -g | awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'
}
port=$((31000 + RANDOM % 20000))
for round in $(seq "$ROUNDS"); do
  a="$OUT/a$round"
  "$BIN" train --config "$OUT/train.toml" --out "$a" --threads "$THREADS" --no-progress 2>"$a.log"
  b="$OUT/b$round"
  half=$((THREADS / 2 > 0 ? THREADS / 2 : 1))
  for r in 0 1; do
    "$BIN" train --config "$OUT/train.toml" --out "$b" --threads "$half" --no-progress \
      --nnodes 2 --node-rank $r --master-addr 127.0.0.1 --master-port $port 2>"$b.rank$r.log" &
  done
  wait
  port=$((port + 10))
  sync_line=$(grep -o 'all-reduce [0-9.]* s ([0-9.]*%)' "$b.rank0.log" || echo "all-reduce ?")
  printf 'round %s: 1 process x %s threads %.2f s/step | 2 processes x %s thread(s) %.2f s/step (%s) | ratio B/A %.3f\n' \
    "$round" "$THREADS" "$(per_step "$a")" "$half" "$(per_step "$b")" "$sync_line" \
    "$(echo "$(per_step "$b") / $(per_step "$a")" | bc -l)"
done
