#!/usr/bin/env bash
# CREStereo on a CUDA machine without Rust or network, in the order a short device call can
# afford: the cold warm-up (time, kernel count by family and cause), parity against the
# fixtures, warm inference and a training step timed against PyTorch on the same GPU with peak
# memory, then one-GPU training through the collective against the plain run.
#
#   gpu_run.sh BIN FIXTURES_DIR TORCH_REFERENCE_PY [OUT_DIR] [DATA_DIR]
#
# BIN: the stripped `crestereo` binary built with `--features cuda` (x86-64).
# FIXTURES_DIR: needs weights_seed0.pt and eval_cascade_1x128x192/{left.png,right.png,pred_full.npy}.
# TORCH_REFERENCE_PY: crates/crestereo/bench/torch_reference.py (needs python3 with torch, numpy).
# OUT_DIR (default $OUT): summary.txt, results.json, census.json, the logs and the predictions.
# DATA_DIR (optional): a small training dataset (any layout `crestereo train --data` reads, e.g.
#   `crestereo synth --out D --count 64 --size 384x512`): 200 training steps on CUDA with their loss.
# SIZES (env, default "infer384 hd paper", most wanted first): what to time — infer384 = inference
#   1x384x512, hd = inference 1x1088x1920 (both two-pass, 20 iterations), paper = a training step
#   2x384x512 at 10 iterations (Burn at --precision f32 against PyTorch with TF32 off, then Burn at
#   tf32 against PyTorch's defaults), small = 1x192x256 training and 256x320 inference.
# REPEATS (env, default 3). PRECISIONS (env, default "f32 tf32"): the Burn precisions timed.
# DEV (env, default cuda): the device of every part (`cpu` runs the script's logic on a machine
#   without a GPU; its figures then mean nothing).
# DEADLINE_S (env, default 480): the script's budget in seconds; a part that cannot start in
#   time is skipped and said so, a running one is stopped at the deadline (what it wrote stays).
# COMPILE_S (env, default 240): how long part 1's cold warm-up may run.
# KERNELS_IN (env, optional): an earlier run's OUT_DIR/kernels.txz (the path without the .00,
#   .01, ... suffix of its parts; a gzip archive is read too) from the same binary: every run
#   leaves the kernels it compiled, and the autotune results, in OUT_DIR/kernels.txz.*, and the
#   next run starts from them.
# COMPILE_LOG (env, optional): CubeCL's log of the cold warm-up in OUT_DIR/cubecl_warmup.log
#   (every kernel's source as compiled).
# The whole script is made to fit one device call of at most 8 minutes on an H100/H200.
set -uo pipefail
BIN=$1
FIX=$2
REF=$3
OUT=${4:-${OUT:?give OUT_DIR or set OUT}}
DATA=${5:-}
SIZES=${SIZES:-infer384 hd paper}
PRECISIONS=${PRECISIONS:-f32 tf32}
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
DEV=${DEV:-cuda}
# AUTOTUNE (env, default minimal): CubeCL's autotune level for every part (what is left of
# autotuning at --precision f32: reductions and fused element-wise kernels; at tf32 matrix
# products and convolutions too).
export CRESTEREO_AUTOTUNE_LEVEL=${AUTOTUNE:-minimal}
WORK=$(mktemp -d)
# The kernel cache: CRESTEREO_KERNEL_CACHE's folder holds one folder per build of the binary,
# named by a hash of its bytes (a copy finds it), with a folder per GPU architecture inside.
export CRESTEREO_KERNEL_CACHE=${CRESTEREO_KERNEL_CACHE:-$HOME/.cache/stereogen/kernels}
KC=$CRESTEREO_KERNEL_CACHE
SHA=$(sha256sum "$BIN" | cut -d' ' -f1)
# Compiled kernels (lines of the `toc` files) and autotune results (lines under `autotune`).
census() {
    local k t
    k=$(find "$KC" -type f -name 'toc*' -not -path '*autotune*' -exec cat {} + 2>/dev/null | wc -l)
    t=$(find "$KC" -type f -path '*autotune*' -exec cat {} + 2>/dev/null | wc -l)
    echo "$k compiled kernels, $t autotune results"
}
# On every exit, the deadline's included: the cache as it stands, for the next run, as
# kernels.txz.00, .01, ... of at most 15 MiB each (a device call returns at most 8 files of
# 16 MiB, 64 MiB in all): the PTX and the autotune results, not the driver's machine code
# (nv/, gigabytes, rebuilt from the PTX). xz -9 because PTX repeats itself across kernels: 2418
# kernels (420 MB) pack into 6.6 MB, against 35 MB with gzip; the packing takes about 20 s on 16
# cores, so end DEADLINE_S 40 s before the device call's limit. Written under a temporary name
# and renamed part by part at the end, so a run stopped mid-write leaves no torn archive.
# KERNEL_PARTS (env, default 4): more parts than that are dropped, and said so.
finish() {
    if [ -d "$KC" ]; then
        echo "$SHA" >"$WORK/BINARY_SHA256"
        rm -f "$OUT"/kernels.txz* "$OUT"/.kernels_part.*
        # The cache folder is stored as `kernels`, whatever CRESTEREO_KERNEL_CACHE is named here.
        if tar cf - --exclude="$(basename "$KC")/nv" --transform "s,^$(basename "$KC"),kernels," \
            -C "$WORK" BINARY_SHA256 -C "$(dirname "$KC")" "$(basename "$KC")" | xz -9 -T0 |
            split -b 15m -d - "$OUT/.kernels_part."; then
            n=$(ls "$OUT"/.kernels_part.* | wc -l)
            if [ "$n" -le "${KERNEL_PARTS:-4}" ]; then
                for part in "$OUT"/.kernels_part.*; do mv "$part" "$OUT/kernels.txz.${part##*.}"; done
                say "kernel cache left in $OUT/kernels.txz.00..: $(census), $n parts"
            else
                rm -f "$OUT"/.kernels_part.*
                say "kernel cache NOT left: $n parts of 15 MiB, over KERNEL_PARTS (${KERNEL_PARTS:-4})"
            fi
        fi
    fi
    rm -rf "$WORK"
}
trap finish EXIT
trap 'exit 143' TERM INT

say "== machine (autotune level $CRESTEREO_AUTOTUNE_LEVEL)"
if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$SUMMARY"
else
    say "no nvidia-smi: GPU memory is not read"
fi
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
if [ -n "${KERNELS_IN:-}" ]; then
    mkdir -p "$WORK/in"
    # One file, or the parts KERNELS_IN.00, .01, ... in order.
    parts=("$KERNELS_IN")
    [ -f "$KERNELS_IN" ] || parts=("$KERNELS_IN".[0-9][0-9])
    unpack() { if [ "$(head -c 6 "${parts[0]}" | od -An -tx1 | tr -d ' ')" = fd377a585a00 ]; then
        xz -dc -T0; else gzip -dc; fi; }
    if cat "${parts[@]}" | unpack | tar x -C "$WORK/in" && [ "$(cat "$WORK/in/BINARY_SHA256")" = "$SHA" ]; then
        mkdir -p "$KC" && cp -r "$WORK/in/kernels/." "$KC/"
        say "kernel cache from $KERNELS_IN: $(census)"
    else
        say "KERNELS_IN ($KERNELS_IN) is not from this binary: ignored, the start is cold"
    fi
    rm -rf "$WORK/in"
fi

# --- 1. the cold warm-up: one `crestereo warmup` compiles every kernel the later parts need
# (the fixture's inference, the timed sizes, the paper's training step), with the kernel census.
# At --precision f32 matrix products and convolutions run one fixed kernel per shape class, so
# nothing is compiled for autotuning them. The CPU prediction for part 2 runs beside it.
E=$FIX/eval_cascade_1x128x192
mkdir -p "${KC:?}"
export CUDA_CACHE_PATH=${CUDA_CACHE_PATH:-$KC/nv} CUDA_CACHE_MAXSIZE=4294967296
CPU_PID=
if [ "$DEV" != cpu ]; then
    nice -n 15 "$BIN" infer "$E/left.png" "$E/right.png" -o "$OUT/pred_cpu.exr" --pfm "$OUT/pred_cpu.pfm" \
        --weights "$FIX/weights_seed0.pt" --iters 20 --stages 2 --device cpu >"$OUT/infer_cpu.log" 2>&1 &
    CPU_PID=$!
fi
WARM_ARGS=(warmup --device "$DEV" --crop 384x512 --batch-size 2 --iters 10 --infer-size 128x192)
for size in $SIZES; do
    case $size in
        infer384) WARM_ARGS+=(--infer-size 384x512) ;;
        hd) WARM_ARGS+=(--infer-size 1088x1920) ;;
        small) WARM_ARGS+=(--infer-size 256x320) ;;
    esac
done
say "== cold warm-up ($(census) in the cache): crestereo ${WARM_ARGS[*]}"
start=$(date +%s.%N)
limit=${COMPILE_S:-240}
[ "$limit" -gt "$(left)" ] && limit=$(left)
(
    [ -n "${COMPILE_LOG:-}" ] && export CUBECL_DEBUG_LOG=$OUT/cubecl_warmup.log
    CRESTEREO_KERNEL_CENSUS=$OUT/census.json exec timeout --kill-after=5 "$limit" "$BIN" "${WARM_ARGS[@]}"
) >"$OUT/warmup_cold.log" 2>&1
rc=$?
wall=$(python3 -c "import time; print(f'{time.time() - $start:.1f}')")
case $rc in 0) st=finished ;; 124|137) st="stopped at COMPILE_S ($limit s)" ;; *) st="FAILED (exit $rc)" ;; esac
say "-- cold warm-up $st after $wall s; cache: $(census)"
grep -E "^(warm-up|  |kernel)" "$OUT/warmup_cold.log" | sed 's/^/   /' | tee -a "$SUMMARY"
case $rc in 0|124|137) ;; *) tail -5 "$OUT/warmup_cold.log" | sed 's/^/   | /' | tee -a "$SUMMARY" ;; esac
# Tensor-core (TF32) kernels must not be compiled at --precision f32.
if [ -s "$OUT/census.json" ]; then
    python3 - "$OUT/census.json" <<'PY' | tee -a "$SUMMARY"
import json, sys
c = json.load(open(sys.argv[1]))
tc = [k for k in c["kernels"] if any(s in k["key"].lower() for s in ("cmma", "mma", "tf32"))]
print(f"   census: {c['total']['run']} run + {c['total']['tuning']} tuning = "
      f"{c['total']['run'] + c['total']['tuning']} kernels, {c['tunings']} autotunings; "
      f"tensor-core kernels: {len(tc)}" + (" (FAIL at f32)" if tc else ""))
for fam, n in sorted(c["by_family"].items()):
    print(f"     {fam:<28} run {n['run']:>4}  tuning {n['tuning']:>4}")
PY
fi
[ -n "$CPU_PID" ] && wait "$CPU_PID"
# A warm process from the filled cache, end to end: what every later job pays.
start=$(date +%s.%N)
in_time "$BIN" infer "$E/left.png" "$E/right.png" -o "$OUT/pred_$DEV.exr" --pfm "$OUT/pred_$DEV.pfm" \
    --weights "$FIX/weights_seed0.pt" --iters 20 --stages 2 --device "$DEV" >"$OUT/parity.log" 2>&1 \
    || say "infer --device $DEV FAILED (see parity.log)"
say "-- warm process: crestereo infer of the fixture pair (two-pass, 20 iterations), $(python3 -c \
    "import time; print(f'{time.time() - $start:.1f}')") s end to end; cache: $(census)"

# --- 2. parity: the CLI's two-pass inference on the fixture PNGs (part 1's warm process and the
# CPU's), vs pred_full.npy
say "== parity (eval_cascade_1x128x192, two-pass, 20 iters) vs pred_full.npy"
python3 - "$OUT" "$E/pred_full.npy" "$DEV" <<'EOF' | tee -a "$SUMMARY"
import sys, numpy as np
out, ref = sys.argv[1], np.load(sys.argv[2])[0, 0]  # (1, 2, H, W) -> disparity channel
def pfm(path):
    with open(path, "rb") as f:
        assert f.readline().strip() == b"Pf"
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    return data.reshape(h, w)[::-1]  # PFM rows run bottom to top
for dev in dict.fromkeys((sys.argv[3], "cpu")):
    try:
        d = pfm(f"{out}/pred_{dev}.pfm")
    except Exception as e:
        print(f"{dev}: no prediction ({e})"); continue
    err = np.abs(d - ref).max()
    print(f"{dev}: max |pred - pred_full| = {err:.3e} ({'PASS' if err <= 1e-3 else 'FAIL'} at 1e-3)")
EOF

# PyTorch's own prediction on the device with TensorFloat-32 off, at its defaults and all on: the
# size of error reduced-precision matrix units give on this input, beside the backend's figure.
[ "$DEV" != cpu ] && CRESTEREO_TORCH_DEVICE=$DEV in_time python3 "$REF" parity "$E" "$FIX/weights_seed0.pt" \
    2>&1 | sed 's/^/   /' | tee -a "$SUMMARY"

if [ ! -s "$OUT/pred_$DEV.pfm" ]; then
    # Nothing below can run without a working backend: stop early, with the reason.
    say "== $DEV inference failed; its log ends:"
    tail -25 "$OUT/parity.log" | tee -a "$SUMMARY"
    exit 1
fi

# --- 3. timing and peak GPU memory, each run in its own process while nvidia-smi polls. Burn
# at each of PRECISIONS; PyTorch with TF32 off beside f32, at its defaults (TF32 in cuDNN
# convolutions) beside tf32.
poll_start() {
    if command -v nvidia-smi >/dev/null; then
        nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 50 >"$1" & POLL=$!
    else echo 0 >"$1"; POLL=; fi
}
poll_stop() { [ -n "$POLL" ] && { kill "$POLL" 2>/dev/null; wait "$POLL" 2>/dev/null; }; }
peak() { sort -n "$1" | tail -1 | grep . || echo 0; }
BASE=$(nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits 2>/dev/null | head -1)
BASE=${BASE:-0}
say "== timing (device sync around every clock reading; warm-up then median of $REPEATS)"
say "   GPU memory in use before the runs: $BASE MiB (subtracted from the nvidia-smi peaks)"
echo "[" >"$OUT/results.json"
first=1
for size in $SIZES; do
    case $size in
        small) TS="1 192 256 4"; IS="256 320"; WHATS="train infer" ;;
        paper) TS="2 384 512 10"; IS=""; WHATS="train" ;;
        infer384) TS=""; IS="384 512"; WHATS="infer" ;;
        hd) TS=""; IS="1088 1920"; WHATS="infer" ;;
        *) say "unknown size $size"; continue ;;
    esac
    for what in $WHATS; do
        if [ $what = train ]; then S=$TS; else S=$IS; fi
        csv=$(echo $S | tr ' ' ',')
        for prec in $PRECISIONS; do
            tf32=off; [ "$prec" = tf32 ] && tf32=default
            tag=${what}_${size}_$prec
            poll_start "$OUT/mem_burn_$tag.txt"
            CRESTEREO_PRECISION=$prec in_time "$BIN" bench --device "$DEV" --what $what --repeats "$REPEATS" \
                $([ $what = train ] && echo --train-size || echo --infer-size) "$csv" \
                >"$OUT/burn_$tag.log" 2>&1 || say "burn $tag FAILED"
            poll_stop
            poll_start "$OUT/mem_torch_$tag.txt"
            CRESTEREO_TORCH_DEVICE=$DEV CRESTEREO_TORCH_REPEATS=$REPEATS CRESTEREO_TORCH_TF32=$tf32 \
                in_time python3 "$REF" bench 8 $what $S >"$OUT/torch_$tag.log" 2>&1 || say "torch $tag FAILED"
            poll_stop
            b=$(grep -E "^(train step|inference)" "$OUT/burn_$tag.log" | tail -1)
            t=$(grep -E "^torch" "$OUT/torch_$tag.log" | tail -1)
            bm=$(( $(peak "$OUT/mem_burn_$tag.txt") - BASE ))
            tm=$(( $(peak "$OUT/mem_torch_$tag.txt") - BASE ))
            say "-- $what $size ($S): burn --precision $prec, torch TF32 $tf32"
            say "   burn : $b | nvidia-smi peak $bm MiB"
            say "   torch: $t | nvidia-smi peak $tm MiB"
            python3 - "$what" "$size" "$b" "$t" "$bm" "$tm" "$first" "$prec" "$tf32" >>"$OUT/results.json" <<'EOF'
import json, re, sys
what, size, b, t, bm, tm, first, prec, tf32 = sys.argv[1:]
def total(line):
    m = re.search(r"total incl\. Adam ([\d.]+)s", line) or re.search(r"\): ([\d.]+)s", line)
    return float(m.group(1)) if m else None
def part(line, name):
    m = re.search(name + r" ([\d.]+)s", line)
    return float(m.group(1)) if m else None
r = {"what": what, "size": size, "burn_precision": prec, "torch_tf32": tf32,
     "burn_s": total(b), "torch_s": total(t),
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
done
echo "]" >>"$OUT/results.json"

# --- 4. one replica through the collective (`--devices DEV:0`) against the plain run, and the
# plain run twice (whether the backend itself repeats its bits): 5 steps of a small config.
say "== one device through the collective vs the plain run (5 steps, batch 1, 192x256, 4 iterations)"
SYN=$WORK/synth
in_time "$BIN" synth --out "$SYN" --count 8 --size 256x320 >"$OUT/synth.log" 2>&1 || say "synth FAILED"
CFG=$WORK/small.toml
cat >"$CFG" <<TOML
seed = 0
steps = 5
batch_size = 1
accumulate = 1
iters = 4
[schedule]
lr = 0.00002
warmup_steps = 0
decay_start = 5
[augment]
crop = [192, 256]
[checkpoint]
every = 5
keep = 1
[log]
tensorboard = false
[[datasets]]
path = "$SYN"
TOML
for run in plain plain_again collective; do
    extra=""
    [ $run = collective ] && extra="--devices $DEV:0"
    in_time "$BIN" train --device "$DEV" --config "$CFG" --out "$WORK/$run" --no-progress $extra \
        >"$OUT/train_$run.log" 2>&1 || say "train $run FAILED (see train_$run.log)"
    in_time "$BIN" export pytorch --weights "$WORK/$run" -o "$WORK/$run.pth" >>"$OUT/train_$run.log" 2>&1
    cp "$WORK/$run/train_log.csv" "$OUT/train_log_$run.csv" 2>/dev/null
done
python3 - "$WORK" <<'EOF' | tee -a "$SUMMARY"
import csv, sys, torch
work = sys.argv[1]
def losses(run):
    with open(f"{work}/{run}/train_log.csv") as f:
        return [float(r["loss"]) for r in csv.DictReader(f)]
def weights(run):
    return torch.load(f"{work}/{run}.pth", map_location="cpu", weights_only=True)
try:
    base_l, base_w = losses("plain"), weights("plain")
except Exception as e:
    print(f"   no plain run to compare with ({e})"); sys.exit()
print(f"   plain losses: {' '.join(f'{x:.6f}' for x in base_l)}")
for run in ("plain_again", "collective"):
    try:
        l, w = losses(run), weights(run)
    except Exception as e:
        print(f"   {run}: missing ({e})"); continue
    dl = max((abs(a - b) / abs(a) for a, b in zip(base_l, l)), default=float("nan"))
    num = sum(float((base_w[k].double() - w[k].double()).pow(2).sum()) for k in base_w)
    den = sum(float(base_w[k].double().pow(2).sum()) for k in base_w)
    same = l == base_l and all(torch.equal(base_w[k], w[k]) for k in base_w)
    print(f"   {run} vs plain: {len(l)} steps, losses {dl:.3e}, weights {(num / den) ** 0.5:.3e} "
          f"(relative){' - bit-identical' if same else ''}")
EOF

# --- 5. 200 training steps on the carried data (paper crop, batch 8) with their loss
if [ -n "$DATA" ]; then
    say "== 200 training steps on $DATA ($DEV, batch 8, 384x512, 10 iters)"
    poll_start "$OUT/mem_train200.txt"
    start=$(date +%s)
    # --accumulate 1: one optimizer step per batch of 8 (the default accumulates 8 batches).
    in_time "$BIN" train --device "$DEV" --data "$DATA" --out "$OUT/run200" --steps 200 --batch-size 8 \
        --accumulate 1 --crop 384x512 --iters 10 --checkpoint-every 200 --no-progress \
        >"$OUT/train200.log" 2>&1 || say "train 200 steps FAILED (see train200.log)"
    poll_stop
    say "   wall $(( $(date +%s) - start )) s, nvidia-smi peak $(( $(peak "$OUT/mem_train200.txt") - BASE )) MiB"
    # Steps reached (all 200, or as many as the deadline allowed), first and last loss.
    [ -f "$OUT/run200/train_log.csv" ] && { head -2 "$OUT/run200/train_log.csv"; tail -1 "$OUT/run200/train_log.csv"; } | tee -a "$SUMMARY"
fi
say "== done; results.json and logs in $OUT"
