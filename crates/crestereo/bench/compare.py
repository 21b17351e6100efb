"""Burn (`crestereo bench`) and PyTorch (`torch_reference.py`) side by side on the same sizes.

Each measurement is its own process (so each peak RSS is its own), the sides take turns (the
order rotates every repeat) and all get the same thread count (RAYON_NUM_THREADS for Burn,
torch.set_num_threads plus OMP/MKL_NUM_THREADS for PyTorch). Prints the CPU and the instruction
sets each side dispatches to, the median time and peak RSS of each side and the ratios
Burn / PyTorch; `--json FILE` also writes them.

    python compare.py --crestereo target/release/crestereo --threads 2 --repeats 3 --sizes small

`--crestereo` may be given more than once as LABEL=PATH (say, a build before and after a change:
both are timed in the same run against the same PyTorch). `--port DIR` adds the public PyTorch
port (a checkout of github.com/ibaiGorordo/CREStereo-Pytorch; not part of this repository) as a
second baseline. `--burn-isa` runs each Burn binary once per named kernel set (CRESTEREO_ISA).
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


def run(cmd, threads, extra_env=None):
    env = dict(os.environ)
    for var in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = str(threads)
    env.update(extra_env or {})
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


def isa_line(who, text):
    """The line in which a side names its CPU and kernels (`crestereo bench`: "cpu: ...",
    torch_reference.py: "reference: ..." / "port ...: ...")."""
    for line in text.splitlines():
        if line.startswith(("cpu: ", "reference: ", "port ")):
            return line
    return "(a build that does not say which kernels it uses)"


def sides(args):
    """(label, command builder, extra environment, kind) for every side of the comparison."""
    out = []
    isas = args.burn_isa.split(",") if args.burn_isa else [None]
    for spec in args.crestereo:
        label, _, path = spec.rpartition("=")
        label = label or "burn"
        for isa in isas:
            name = f"{label}/{isa}" if isa else label
            env = {"CRESTEREO_ISA": isa} if isa else {}
            out.append((name, burn_command(args, path), env, "burn"))
    torch_cmd = lambda what, size: [args.python, str(HERE / "torch_reference.py"), "bench", str(args.threads), what] + [str(v) for v in size]
    out.append(("torch", torch_cmd, {"CRESTEREO_TORCH_PORT": ""}, "torch"))
    if args.port:
        out.append(("port", torch_cmd, {"CRESTEREO_TORCH_PORT": str(Path(args.port).resolve())}, "torch"))
    return out


def burn_command(args, path):
    def build(what, size):
        sz = ",".join(map(str, size))
        cmd = [path, "bench", "--what", what, "--threads", str(args.threads)]
        return cmd + (["--train-size", sz] if what == "train" else ["--infer-size", sz])
    return build


def median(rows, key):
    return statistics.median(r[key] for r in rows)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--crestereo", required=True, action="append",
                   help="a crestereo binary (release build), or LABEL=PATH; repeatable")
    p.add_argument("--python", default=sys.executable, help="Python with PyTorch (default: this one)")
    p.add_argument("--port", help="checkout of the public PyTorch port, timed as a second baseline")
    p.add_argument("--burn-isa", help="comma-separated kernel sets to run each binary with (CRESTEREO_ISA)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--sizes", default="small", help="small, paper or all")
    p.add_argument("--what", default="all", choices=["all", "train", "infer"])
    p.add_argument("--json", help="also write the medians here")
    args = p.parse_args()
    names = ["small", "paper"] if args.sizes == "all" else [args.sizes]
    every = sides(args)
    results, isas = [], {}
    for name in names:
        for what, size in SIZES[name]:
            if args.what not in ("all", what):
                continue
            rows = {label: [] for label, *_ in every}
            for rep in range(args.repeats):
                k = rep % len(every)
                for label, build, env, _ in every[k:] + every[:k]:
                    text = run(build(what, size), args.threads, env)
                    isas.setdefault(label, isa_line(label, text))
                    r = parse(what, text)
                    rows[label].append(r)
                    print(f"  {name} {what} {size} rep {rep} {label}: {r}", flush=True)
            res = {"size": name, "what": what, "dims": size, "threads": args.threads, "repeats": args.repeats}
            for label in rows:
                res[label] = {k: median(rows[label], k) for k in rows[label][0]}
            for label, _, _, kind in every:
                if kind != "burn":
                    continue
                for base in [b for b, _, _, k in every if k == "torch"]:
                    key = "" if base == "torch" else f"_vs_{base}"
                    res[label][f"ratio_time{key}"] = res[label]["time_s"] / res[base]["time_s"]
                    res[label][f"ratio_peak_rss{key}"] = res[label]["peak_rss_mib"] / res[base]["peak_rss_mib"]
                    if what == "train":
                        res[label][f"ratio_forward{key}"] = res[label]["forward_s"] / res[base]["forward_s"]
                        res[label][f"ratio_backward{key}"] = res[label]["backward_s"] / res[base]["backward_s"]
            results.append(res)
    print(f"\nmedians of {args.repeats} (threads {args.threads}; ratios Burn / PyTorch reference"
          f"{', and / port' if args.port else ''})")
    for label, line in isas.items():
        print(f"  {label:<14} {line}")
    print(f"{'case':<24}{'side':<16}{'time':>10}{'memory':>10}{'time':>8}{'memory':>8}{'fwd':>7}{'bwd':>7}"
          f"{'  vs port' if args.port else ''}")
    for r in results:
        case = f"{r['what']} {'x'.join(map(str, r['dims']))}"
        for label, _, _, kind in every:
            v = r[label]
            line = f"{case:<24}{label:<16}{v['time_s']:>9.2f}s{v['peak_rss_mib']:>7.0f}MiB"
            if kind == "burn":
                line += f"{v['ratio_time']:>7.2f}x{v['ratio_peak_rss']:>7.2f}x"
                if r["what"] == "train":
                    line += f"{v['ratio_forward']:>6.2f}x{v['ratio_backward']:>6.2f}x"
                else:
                    line += " " * 14
                if args.port:
                    line += f"{v['ratio_time_vs_port']:>8.2f}x"
            elif r["what"] == "train":
                line += f"{'':>16}  fwd {v['forward_s']:.2f}s bwd {v['backward_s']:.2f}s"
            print(line)
            case = ""
    if args.json:
        Path(args.json).write_text(json.dumps({"sides": isas, "results": results}, indent=2))


if __name__ == "__main__":
    main()
