"""Burn (`crestereo bench`) and PyTorch (`torch_reference.py`) side by side on the same sizes.

Each measurement is its own process (so each peak RSS is its own), the two alternate (Burn first
on even repeats, PyTorch first on odd ones) and both get the same thread count (RAYON_NUM_THREADS
for Burn, torch.set_num_threads plus OMP/MKL_NUM_THREADS for PyTorch). Prints the median time and
peak RSS of each and the ratios Burn / PyTorch; `--json FILE` also writes them.

    python compare.py --crestereo target/release/crestereo --threads 2 --repeats 3 --sizes small
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# name -> (what, size args)
SIZES = {
    "small": [("train", [1, 192, 256, 4]), ("infer", [256, 320])],
    "paper": [("train", [2, 384, 512, 10]), ("infer", [480, 640])],
}

TRAIN = re.compile(
    r"forward ([\d.]+)s, backward ([\d.]+)s, total incl\. Adam ([\d.]+)s, peak RSS (\d+) MiB"
)
INFER = re.compile(r"\): ([\d.]+)s, peak RSS (\d+) MiB")


def run(cmd, threads):
    env = dict(os.environ)
    for var in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(threads)
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"failed ({out.returncode}): {' '.join(map(str, cmd))}\n{out.stdout}\n{out.stderr}")
    return out.stdout + out.stderr


def parse(what, text):
    if what == "train":
        m = TRAIN.search(text)
        if not m:
            sys.exit(f"no timing line in:\n{text}")
        fwd, bwd, total, rss = m.groups()
        return {"forward_s": float(fwd), "backward_s": float(bwd), "time_s": float(total), "peak_rss_mib": float(rss)}
    m = INFER.search(text)
    if not m:
        sys.exit(f"no timing line in:\n{text}")
    return {"time_s": float(m.group(1)), "peak_rss_mib": float(m.group(2))}


def commands(args, what, size):
    sz = ",".join(map(str, size))
    burn = [args.crestereo, "bench", "--what", what, "--threads", str(args.threads)]
    burn += ["--train-size", sz] if what == "train" else ["--infer-size", sz]
    torch = [args.python, str(HERE / "torch_reference.py"), "bench", str(args.threads), what]
    torch += [str(v) for v in size]
    return {"burn": burn, "torch": torch}


def median(rows, key):
    return statistics.median(r[key] for r in rows)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--crestereo", required=True, help="the crestereo binary (release build)")
    p.add_argument("--python", default=sys.executable, help="Python with PyTorch (default: this one)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--sizes", default="small", help="small, paper or all")
    p.add_argument("--what", default="all", choices=["all", "train", "infer"])
    p.add_argument("--json", help="also write the medians here")
    args = p.parse_args()
    names = ["small", "paper"] if args.sizes == "all" else [args.sizes]
    results = []
    for name in names:
        for what, size in SIZES[name]:
            if args.what not in ("all", what):
                continue
            cmds = commands(args, what, size)
            rows = {"burn": [], "torch": []}
            for rep in range(args.repeats):
                order = ["burn", "torch"] if rep % 2 == 0 else ["torch", "burn"]
                for who in order:
                    r = parse(what, run(cmds[who], args.threads))
                    rows[who].append(r)
                    print(f"  {name} {what} {size} rep {rep} {who}: {r}", flush=True)
            res = {"size": name, "what": what, "dims": size, "threads": args.threads, "repeats": args.repeats}
            for who in ("burn", "torch"):
                res[who] = {k: median(rows[who], k) for k in rows[who][0]}
            res["ratio_time"] = res["burn"]["time_s"] / res["torch"]["time_s"]
            res["ratio_peak_rss"] = res["burn"]["peak_rss_mib"] / res["torch"]["peak_rss_mib"]
            if what == "train":
                res["ratio_forward"] = res["burn"]["forward_s"] / res["torch"]["forward_s"]
                res["ratio_backward"] = res["burn"]["backward_s"] / res["torch"]["backward_s"]
            results.append(res)
    print(f"\nmedians of {args.repeats} (threads {args.threads}; Burn / PyTorch)")
    print(f"{'case':<34}{'Burn':>22}{'PyTorch':>22}{'time':>8}{'memory':>8}")
    for r in results:
        case = f"{r['what']} {'x'.join(map(str, r['dims']))}"
        b, t = r["burn"], r["torch"]
        print(f"{case:<34}{b['time_s']:>9.2f}s {b['peak_rss_mib']:>7.0f}MiB "
              f"{t['time_s']:>9.2f}s {t['peak_rss_mib']:>7.0f}MiB {r['ratio_time']:>7.2f}x {r['ratio_peak_rss']:>6.2f}x")
        if r["what"] == "train":
            print(f"{'  forward / backward':<34}{b['forward_s']:>6.2f}/{b['backward_s']:<6.2f}s{'':>8}"
                  f"{t['forward_s']:>6.2f}/{t['backward_s']:<6.2f}s{'':>8}"
                  f"{r['ratio_forward']:.2f}x / {r['ratio_backward']:.2f}x")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
