"""Decode one stereo sample (2 PNG + 2 float EXR) through the stereogen module and through
Pillow + OpenEXR, the code a Python user would write. Prints one JSON line of timings.

Usage: python bench_decode.py DATASET_DIR REPEATS
"""

import json
import pathlib
import sys
import time

import numpy as np
import OpenEXR
from PIL import Image

import stereogen

root = pathlib.Path(sys.argv[1])
repeats = int(sys.argv[2])
line = json.loads((root / "manifest.jsonl").read_text().splitlines()[0])
files = {k: str(root / v) for k, v in line["files"].items()}


def with_stereogen(ds):
    s = ds[0]
    return s["left"], s["right"], s["disp_left"], s["valid_left"], s["disp_right"]


def with_pillow_openexr():
    left = np.asarray(Image.open(files["left"]).convert("RGB"))
    right = np.asarray(Image.open(files["right"]).convert("RGB"))
    out = [left, right]
    for key in ("disp_left", "disp_right"):
        with OpenEXR.File(files[key], separate_channels=True) as f:
            ch = f.channels()
            out.append(np.asarray(ch["Y"].pixels, dtype=np.float32))
            out.append(np.asarray(ch["valid"].pixels) > 0.5)
    return out


def timed(fn, *args):
    t0 = time.perf_counter()
    fn(*args)
    return time.perf_counter() - t0


ds = stereogen.open_dataset(str(root))
a = with_stereogen(ds)
b = with_pillow_openexr()
# Both paths must decode the same values before their speed means anything.
np.testing.assert_array_equal(a[0], b[0])
np.testing.assert_array_equal(a[2], b[2])
np.testing.assert_array_equal(a[3], b[3])
np.testing.assert_array_equal(a[4], b[4])
# Interleaved, so a load change on a shared machine hits both decoders alike.
ts, tp = [], []
for _ in range(repeats):
    ts.append(timed(with_stereogen, ds))
    tp.append(timed(with_pillow_openexr))
ts.sort()
tp.sort()
s_min, s_med, p_min, p_med = ts[0], ts[len(ts) // 2], tp[0], tp[len(tp) // 2]
print(json.dumps({"stereogen_min": s_min, "stereogen_median": s_med, "pillow_openexr_min": p_min, "pillow_openexr_median": p_med}))
