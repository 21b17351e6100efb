"""Runs a `crestereo export onnx` graph with onnxruntime (CPU), after ONNX's own checker.

    python onnx_run.py model.onnx --check --pair left.npy right.npy out.npy [--pair ...]
    python onnx_run.py model.onnx --time 480x640 --threads 2 --repeats 3

`--check`: `onnx.checker.check_model(full_check=True)` (types and shapes inferred for every
node). `--pair L R OUT`: runs the graph on two (1, 3, H, W) float32 arrays (BGR, 0..255, what
the reference model takes) and writes the disparity (1, 1, H, W) to OUT. `--time HxW`: a random
pair of that size: the first run (timed on its own), then the median of `--repeats` more. Prints one JSON
object: the op types, node count and size of the graph, and the timings.
"""
import argparse
import json
import statistics
import time

import numpy as np
import onnx
import onnxruntime as ort


def main():
    p = argparse.ArgumentParser()
    p.add_argument("model")
    p.add_argument("--check", action="store_true")
    p.add_argument("--pair", nargs=3, action="append", default=[], metavar=("LEFT", "RIGHT", "OUT"))
    p.add_argument("--time", metavar="HxW")
    p.add_argument("--threads", type=int, default=0, help="intra-op threads (0: onnxruntime's default)")
    p.add_argument("--repeats", type=int, default=3)
    a = p.parse_args()

    model = onnx.load(a.model)
    report = {
        "op_types": sorted({n.op_type for n in model.graph.node}),
        "nodes": len(model.graph.node),
        "opset": [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")],
        "domains": sorted({n.domain for n in model.graph.node}),
        "inputs": {i.name: [d.dim_value for d in i.type.tensor_type.shape.dim] for i in model.graph.input},
        "outputs": {o.name: [d.dim_value for d in o.type.tensor_type.shape.dim] for o in model.graph.output},
    }
    if a.check:
        onnx.checker.check_model(a.model, full_check=True)
        report["checker"] = "passed (full_check=True)"

    opts = ort.SessionOptions()
    if a.threads:
        opts.intra_op_num_threads = a.threads
        opts.inter_op_num_threads = 1
    session = ort.InferenceSession(a.model, opts, providers=["CPUExecutionProvider"])
    report["onnxruntime"] = ort.__version__
    for left, right, out in a.pair:
        feed = {"left": np.load(left).astype(np.float32), "right": np.load(right).astype(np.float32)}
        (disparity,) = session.run(["disparity"], feed)
        np.save(out, disparity.astype(np.float32))
    if a.time:
        h, w = (int(v) for v in a.time.lower().split("x"))
        rng = np.random.default_rng(0)
        feed = {k: rng.integers(0, 256, (1, 3, h, w)).astype(np.float32) for k in ("left", "right")}
        t0 = time.perf_counter()
        session.run(["disparity"], feed)
        report["first_run_s"] = time.perf_counter() - t0
        times = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            session.run(["disparity"], feed)
            times.append(time.perf_counter() - t0)
        report["seconds"] = times
        report["median_s"] = statistics.median(times)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
