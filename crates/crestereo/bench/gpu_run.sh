#!/usr/bin/env bash
# CREStereo on a CUDA machine without Rust or network: parity against the fixtures, then Burn
# (CUDA) and PyTorch (CUDA) timed on the same GPU, with peak GPU memory.
#
#   gpu_run.sh BIN FIXTURES_DIR TORCH_REFERENCE_PY [OUT_DIR] [DATA_DIR]
#
# BIN: the stripped `crestereo` binary built with `--features cuda` (x86-64).
# FIXTURES_DIR: needs weights_seed0.pt and eval_cascade_1x128x192/{left.png,right.png,pred_full.npy}.
# TORCH_REFERENCE_PY: crates/crestereo/bench/torch_reference.py (needs python3 with torch, numpy).
# OUT_DIR (default $OUT): summary.txt, results.json, the logs and the predictions.
# DATA_DIR (optional): a small training dataset (any layout `crestereo train --data` reads, e.g.
#   `crestereo synth --out D --count 64 --size 384x512`): 200 training steps on CUDA with their loss.
# SIZES (env, default "paper8 paper hd small", most wanted first): which sizes to time (hd =
#   1088x1920 inference, paper8 = the paper crop at batch 8). REPEATS (env, default 3).
# DEADLINE_S (env, default 480): the script's budget in seconds; a part that cannot start in
#   time is skipped and said so, a running one is stopped at the deadline (what it wrote stays).
# The whole script is made to fit one device call of at most 8 minutes on an H100/H200.
set -uo pipefail
BIN=$1
FIX=$2
REF=$3
OUT=${4:-${OUT:?give OUT_DIR or set OUT}}
DATA=${5:-}
SIZES=${SIZES:-paper8 paper hd small}
REPEATS=${REPEATS:-3}
DEADLINE=$(( $(date +%s) + ${DEADLINE_S:-480} ))
mkdir -p "$OUT"
SUMMARY=$OUT/summary.txt
: >"$SUMMARY"
say() { echo "$*" | tee -a "$SUMMARY"; }
left() { echo $(( DEADLINE - $(date +%s) )); }
# Runs "$@" with what is left of the budget as its limit; false (and said) when out of time.
in_time() {
    local l; l=$(left)
    if [ "$l" -lt 15 ]; then say "   skipped (deadline): $*"; return 124; fi
    timeout --kill-after=5 "$l" "$@"
}
chmod +x "$BIN" 2>/dev/null || true

say "== machine"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$SUMMARY"
# PyTorch's defaults are timed as they are: TF32 in cuDNN convolutions, fp32 matrix products.
python3 -c 'import torch; b = torch.backends; print("torch", torch.__version__, "cuda", torch.version.cuda,
    "cudnn.allow_tf32", b.cudnn.allow_tf32, "matmul.allow_tf32", b.cuda.matmul.allow_tf32)' | tee -a "$SUMMARY"

# CubeCL compiles its kernels at run time with NVRTC and the toolkit's headers: CUDA_PATH (the
# toolkit root, with include/) from nvcc when unset, libnvrtc from the toolkit or the pip wheels.
if [ -z "${CUDA_PATH:-}" ] && command -v nvcc >/dev/null; then
    CUDA_PATH=$(dirname "$(dirname "$(readlink -f "$(command -v nvcc)")")")
    export CUDA_PATH
fi
for lib in libnvrtc.so libcuda.so.1; do
    if ! ldconfig -p | grep -q "$lib"; then
        dir=$(find "${CUDA_PATH:-/usr/local/cuda}" /usr/local/cuda* /usr/local/nvidia /opt /usr/lib \
            -name "$lib*" -print 2>/dev/null | head -1)
        [ -n "$dir" ] && export LD_LIBRARY_PATH=$(dirname "$dir")${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
    fi
done
say "CUDA_PATH=${CUDA_PATH:-unset} LD_LIBRARY_PATH=${LD_LIBRARY_PATH:-unset}"

# --- 1. parity: the CLI's two-pass inference on the fixture PNGs, CUDA and CPU, vs pred_full.npy
say "== parity (eval_cascade_1x128x192, two-pass, 20 iters) vs pred_full.npy"
E=$FIX/eval_cascade_1x128x192
for dev in cuda cpu; do
    in_time "$BIN" infer "$E/left.png" "$E/right.png" -o "$OUT/pred_$dev.exr" --pfm "$OUT/pred_$dev.pfm" \
        --weights "$FIX/weights_seed0.pt" --iters 20 --stages 2 --device "$dev" \
        >"$OUT/infer_$dev.log" 2>&1 || say "infer --device $dev FAILED (see infer_$dev.log)"
done
python3 - "$OUT" "$E/pred_full.npy" <<'EOF' | tee -a "$SUMMARY"
import sys, numpy as np
out, ref = sys.argv[1], np.load(sys.argv[2])[0, 0]  # (1, 2, H, W) -> disparity channel
def pfm(path):
    with open(path, "rb") as f:
        assert f.readline().strip() == b"Pf"
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return data.reshape(h, w)[::-1]  # PFM rows run bottom to top
for dev in ("cuda", "cpu"):
    try:
        d = pfm(f"{out}/pred_{dev}.pfm")
    except Exception as e:
        print(f"{dev}: no prediction ({e})"); continue
    err = np.abs(d - ref).max()
    print(f"{dev}: max |pred - pred_full| = {err:.3e} ({'PASS' if err <= 1e-3 else 'FAIL'} at 1e-3)")
EOF

if [ ! -s "$OUT/pred_cuda.pfm" ]; then
    # Nothing below can run without a working CUDA backend: stop early, with the reason.
    say "== CUDA inference failed; its log ends:"
    tail -25 "$OUT/infer_cuda.log" | tee -a "$SUMMARY"
    exit 1
fi

# --- 2. timing and peak GPU memory, each run in its own process while nvidia-smi polls
poll_start() { nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 50 >"$1" & POLL=$!; }
poll_stop() { kill "$POLL" 2>/dev/null; wait "$POLL" 2>/dev/null; }
peak() { sort -n "$1" | tail -1; }
BASE=$(nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits | head -1)
say "== timing (device sync around every clock reading; warm-up then median of $REPEATS)"
say "   GPU memory in use before the runs: $BASE MiB (subtracted from the nvidia-smi peaks)"
echo "[" >"$OUT/results.json"
first=1
for size in $SIZES; do
    case $size in
        small) TS="1 192 256 4"; IS="256 320"; WHATS="train infer" ;;
        paper) TS="2 384 512 10"; IS="480 640"; WHATS="train infer" ;;
        paper8) TS="8 384 512 10"; IS=""; WHATS="train" ;;
        hd) TS=""; IS="1088 1920"; WHATS="infer" ;;
        *) say "unknown size $size"; continue ;;
    esac
    for what in $WHATS; do
        if [ $what = train ]; then S=$TS; else S=$IS; fi
        csv=$(echo $S | tr ' ' ',')
        poll_start "$OUT/mem_burn_${what}_$size.txt"
        in_time "$BIN" bench --device cuda --what $what --repeats "$REPEATS" \
            $([ $what = train ] && echo --train-size || echo --infer-size) "$csv" \
            >"$OUT/burn_${what}_$size.log" 2>&1 || say "burn $what $size FAILED"
        poll_stop
        poll_start "$OUT/mem_torch_${what}_$size.txt"
        CRESTEREO_TORCH_DEVICE=cuda CRESTEREO_TORCH_REPEATS=$REPEATS \
            in_time python3 "$REF" bench 8 $what $S >"$OUT/torch_${what}_$size.log" 2>&1 || say "torch $what $size FAILED"
        poll_stop
        b=$(grep -E "^(train step|inference)" "$OUT/burn_${what}_$size.log" | tail -1)
        t=$(grep -E "^torch" "$OUT/torch_${what}_$size.log" | tail -1)
        bm=$(( $(peak "$OUT/mem_burn_${what}_$size.txt") - BASE ))
        tm=$(( $(peak "$OUT/mem_torch_${what}_$size.txt") - BASE ))
        say "-- $what $size ($S)"
        say "   burn : $b | nvidia-smi peak $bm MiB"
        say "   torch: $t | nvidia-smi peak $tm MiB"
        python3 - "$what" "$size" "$b" "$t" "$bm" "$tm" "$first" >>"$OUT/results.json" <<'EOF'
import json, re, sys
what, size, b, t, bm, tm, first = sys.argv[1:]
def total(line):
    m = re.search(r"total incl\. Adam ([\d.]+)s", line) or re.search(r"\): ([\d.]+)s", line)
    return float(m.group(1)) if m else None
def part(line, name):
    m = re.search(name + r" ([\d.]+)s", line)
    return float(m.group(1)) if m else None
r = {"what": what, "size": size, "burn_s": total(b), "torch_s": total(t),
     "burn_gpu_peak_mib": int(bm), "torch_gpu_peak_mib": int(tm)}
m = re.search(r"max_memory_allocated (\d+) MiB", t)
r["torch_max_memory_allocated_mib"] = int(m.group(1)) if m else None
if what == "train":
    for k in ("forward", "backward"):
        r[f"burn_{k}_s"], r[f"torch_{k}_s"] = part(b, k), part(t, k)
if r["burn_s"] and r["torch_s"]:
    r["ratio_time"] = r["burn_s"] / r["torch_s"]
r["ratio_gpu_peak"] = int(bm) / max(int(tm), 1)
print(("" if first == "1" else ",") + json.dumps(r))
EOF
        first=0
    done
done
echo "]" >>"$OUT/results.json"

# --- 3. 200 training steps on the carried data (paper crop, batch 8) with their loss
if [ -n "$DATA" ]; then
    say "== 200 training steps on $DATA (CUDA, batch 8, 384x512, 10 iters)"
    poll_start "$OUT/mem_train200.txt"
    start=$(date +%s)
    # --accumulate 1: one optimizer step per batch of 8 (the default accumulates 8 batches).
    in_time "$BIN" train --device cuda --data "$DATA" --out "$OUT/run200" --steps 200 --batch-size 8 \
        --accumulate 1 --crop 384x512 --iters 10 --checkpoint-every 200 --no-progress \
        >"$OUT/train200.log" 2>&1 || say "train 200 steps FAILED (see train200.log)"
    poll_stop
    say "   wall $(( $(date +%s) - start )) s, nvidia-smi peak $(( $(peak "$OUT/mem_train200.txt") - BASE )) MiB"
    # Steps reached (all 200, or as many as the deadline allowed), first and last loss.
    [ -f "$OUT/run200/train_log.csv" ] && { head -2 "$OUT/run200/train_log.csv"; tail -1 "$OUT/run200/train_log.csv"; } | tee -a "$SUMMARY"
fi
say "== done; results.json and logs in $OUT"
