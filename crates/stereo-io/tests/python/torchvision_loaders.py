"""Opens our exports with torchvision's own stereo datasets and saves what they return.

    python torchvision_loaders.py EXPORTS OUT

EXPORTS holds `Kitti2012/`, `Kitti2015/` and `CREStereo/` (the folder names torchvision looks
for under its `root`). For each dataset: OUT/<name>/<i>_left.npy, _right.npy (H, W, 3 float32)
and _disp.npy (H, W float32, 0 where torchvision says none), in the loader's order, and one line
of JSON on stdout: {name: [the left image path of each sample, relative to the dataset's folder]}.
"""
import json
import sys
from pathlib import Path

import numpy as np
from torchvision.datasets import CREStereo, Kitti2012Stereo, Kitti2015Stereo

exports, out = Path(sys.argv[1]), Path(sys.argv[2])
found = {}
for name, dataset in [
    ("Kitti2012", Kitti2012Stereo(exports, split="train")),
    ("Kitti2015", Kitti2015Stereo(exports, split="train")),
    ("CREStereo", CREStereo(exports)),
]:
    folder = out / name
    folder.mkdir(parents=True)
    found[name] = []
    for i in range(len(dataset)):
        left, right, disp, _valid = dataset[i]
        np.save(folder / f"{i}_left.npy", np.asarray(left, dtype=np.float32))
        np.save(folder / f"{i}_right.npy", np.asarray(right, dtype=np.float32))
        np.save(folder / f"{i}_disp.npy", np.asarray(disp, dtype=np.float32)[0])
        left_path = Path(dataset._images[i][0])
        found[name].append(str(left_path.relative_to(exports / name)))
print(json.dumps(found))
