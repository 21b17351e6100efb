"""Iterates our WebDataset shards with the `webdataset` package and decodes every member with
Pillow (images) and OpenEXR (disparities), as a training pipeline would.

    python webdataset_reader.py EXPORT OUT

For each sample, in the order `webdataset` yields them (each split's shards from its index, in
order; no shuffling): OUT/<n>_left.npy, _right.npy (H, W, 3 float32), _disp_left.npy and
_disp_right.npy (H, W float32, NaN where the EXR's `valid` channel is 0), and for each map
member the sample has (`depth_left.exr`, `normals_left.exr`, `instance_left.png`,
`semantic_left.png` and the right view's) OUT/<n>_<map>_<view>.npy as float32: depth H x W
(channel `Y`), normals H x W x 3 (channels `R`, `G`, `B`), ids H x W (the 16-bit grey values).
Prints one line of JSON: the sample keys in that order, with the map members each has.
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


def exr_channels(data: bytes) -> dict:
    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(data)
        f.flush()
        with OpenEXR.File(f.name, separate_channels=True) as e:
            # Our EXRs are one named part ("disparity", "depth", "normals"); File.channels()
            # lists unnamed parts only; R, G, B stay separate channels.
            return dict(e.parts[0].channels)


def exr(data: bytes, names=("Y", "valid")) -> np.ndarray:
    channels = exr_channels(data)

    def channel(name):
        found = [c for n, c in channels.items() if n.split(".")[-1] == name]
        if len(found) != 1:
            raise SystemExit(f"no single channel {name!r} among {sorted(channels)}")
        return found[0].pixels

    if names != ("Y", "valid"):
        return np.stack([channel(n) for n in names], axis=-1).astype(np.float32)
    value, valid = channel("Y"), channel("valid")
    return np.where(valid > 0.5, value, np.nan).astype(np.float32)


def ids(data: bytes) -> np.ndarray:
    image = Image.open(io.BytesIO(data))
    if image.mode not in ("I;16", "I;16B", "I"):
        raise SystemExit(f"an id map is 16-bit grey, this one is {image.mode}")
    return np.asarray(image).astype(np.float32)


MAPS = {
    "depth": ("exr", lambda b: exr(b, ("Y",))[..., 0]),
    "normals": ("exr", lambda b: exr(b, ("R", "G", "B"))),
    "instance": ("png", ids),
    "semantic": ("png", ids),
}


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
    maps = []
    for kind, (ext, decode) in MAPS.items():
        for view in ("left", "right"):
            member = f"{kind}_{view}.{ext}"
            if member in sample:
                np.save(out / f"{n}_{kind}_{view}.npy", decode(sample[member]))
                maps.append(member)
    facts = json.loads(sample["json"])
    keys.append({"key": sample["__key__"], "id": facts["id"], "maps": maps})
print(json.dumps(keys))
