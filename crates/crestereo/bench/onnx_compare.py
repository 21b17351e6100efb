"""onnxruntime (CPU) against `crestereo infer`'s computation on the same size and threads.

    python onnx_compare.py --crestereo target/release/crestereo --weights W --size 480x640 \\
        --threads 2 --repeats 3

Run it with a Python that has onnxruntime, onnx and numpy (the test venv of
crates/crestereo-train/tests/integration/export_onnx.rs has them). Exports the graph once (two-pass cascade, 20 iterations), then
alternates, `--repeats` times, one `crestereo bench --what infer` process (the first inference
after the model is made, as a user's `crestereo infer` runs it) and one onnxruntime process
(`onnx_run.py --time`: the first run after the session is made, then the median of 3 more).
Both get the same thread count. Prints the medians and the ratios onnxruntime / Burn.
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
BURN = re.compile(r"\): ([\d.]+)s, peak RSS (\d+) MiB")


def run(cmd, threads):
    env = dict(os.environ)
    for var in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS"):
        env[var] = str(threads)
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"failed ({out.returncode}): {' '.join(map(str, cmd))}\n{out.stdout}\n{out.stderr}")
    return out.stdout + out.stderr


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--crestereo", required=True)
    p.add_argument("--weights", required=True)
    p.add_argument("--size", default="480x640")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()
    h, w = (int(v) for v in a.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "model.onnx"
        run([a.crestereo, "export", "onnx", "--weights", a.weights, "--size", a.size, "-o", model], a.threads)
        burn, ort_first, ort_warm = [], [], []
        for _ in range(a.repeats):
            text = run([a.crestereo, "bench", "--what", "infer", "--threads", str(a.threads),
                        "--infer-size", f"{h},{w}"], a.threads)
            burn.append(float(BURN.search(text).group(1)))
            report = json.loads(run([sys.executable, HERE / "onnx_run.py", model, "--time", a.size,
                                     "--threads", str(a.threads), "--repeats", "3"], a.threads))
            ort_first.append(report["first_run_s"])
            ort_warm.append(report["median_s"])
    b, f, m = (statistics.median(v) for v in (burn, ort_first, ort_warm))
    print(f"inference {h}x{w}, two-pass, 20 iterations, {a.threads} threads, median of {a.repeats}:")
    print(f"  crestereo (Burn, Flex)        {b:7.2f} s   runs {burn}")
    print(f"  onnxruntime, first run        {f:7.2f} s   ({f / b:.2f}x Burn)   runs {[round(v, 2) for v in ort_first]}")
    print(f"  onnxruntime, later runs       {m:7.2f} s   ({m / b:.2f}x Burn)   runs {[round(v, 2) for v in ort_warm]}")


if __name__ == "__main__":
    main()
