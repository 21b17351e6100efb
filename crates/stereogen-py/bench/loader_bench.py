"""Samples per second of `stereogen.torch` through a PyTorch DataLoader.

    python loader_bench.py shards|folder PATH WORKERS [EPOCHS]

`shards` streams a WebDataset export's `train` split with `StereoWebDataset`; `folder` reads a
dataset folder with `StereoDataset`. Batches of 8, WORKERS DataLoader worker processes (0: in this
process), EPOCHS passes (default 2) after one untimed pass that starts the workers and warms the
page cache. Prints one line: samples, seconds, samples/s.
"""

import sys
import time

import torch

from stereogen.torch import StereoDataset, StereoWebDataset

kind, path, workers = sys.argv[1], sys.argv[2], int(sys.argv[3])
epochs = int(sys.argv[4]) if len(sys.argv) > 4 else 2
data = StereoWebDataset(path, split="train") if kind == "shards" else StereoDataset(path)
loader = torch.utils.data.DataLoader(
    data, batch_size=8, num_workers=workers, persistent_workers=workers > 0
)
for _ in loader:
    pass
n, t = 0, time.perf_counter()
for _ in range(epochs):
    for batch in loader:
        n += len(batch["id"])
dt = time.perf_counter() - t
print(f"{kind} workers={workers}: {n} samples in {dt:.2f} s = {n / dt:.1f} samples/s")
