"""Iterates our WebDataset shards with the `webdataset` package and decodes every member with
Pillow (images) and OpenEXR (disparities), as a training pipeline would.

    python webdataset_reader.py EXPORT OUT

For each sample, in the order `webdataset` yields them (each split's shards from its index, in
order; no shuffling): OUT/<n>_left.npy, _right.npy (H, W, 3 float32), _disp_left.npy and
_disp_right.npy (H, W float32, NaN where the EXR's `valid` channel is 0). Prints one line of
JSON: the sample keys in that order.
"""
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
import webdataset as wds
from PIL import Image

export, out = Path(sys.argv[1]), Path(sys.argv[2])
out.mkdir(parents=True)
urls = []
for index in sorted(export.glob("*.index.json")):
    urls += [str(export / s["name"]) for s in json.loads(index.read_text())["shards"]]


def exr(data: bytes) -> np.ndarray:
    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(data)
        f.flush()
        with OpenEXR.File(f.name) as e:
            # Our EXRs are one part named "disparity"; File.channels() lists unnamed parts only.
            channels = dict(e.parts[0].channels)
    def channel(name):
        found = [c for n, c in channels.items() if n.split(".")[-1] == name]
        if len(found) != 1:
            raise SystemExit(f"no single channel {name!r} among {sorted(channels)}")
        return found[0].pixels

    value, valid = channel("Y"), channel("valid")
    return np.where(valid > 0.5, value, np.nan).astype(np.float32)


def rgb(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), dtype=np.float32)


keys = []
for n, sample in enumerate(wds.WebDataset(urls, shardshuffle=False, empty_check=False)):
    image_ext = {"left": None, "right": None}
    for view in image_ext:
        image_ext[view] = next(k for k in sample if k.startswith(view + "."))
    np.save(out / f"{n}_left.npy", rgb(sample[image_ext["left"]]))
    np.save(out / f"{n}_right.npy", rgb(sample[image_ext["right"]]))
    np.save(out / f"{n}_disp_left.npy", exr(sample["disp_left.exr"]))
    if "disp_right.exr" in sample:
        np.save(out / f"{n}_disp_right.npy", exr(sample["disp_right.exr"]))
    facts = json.loads(sample["json"])
    keys.append({"key": sample["__key__"], "id": facts["id"]})
print(json.dumps(keys))
