"""Run by tests/integration/python_wheel.rs in a fresh venv holding the `stereogen` wheel,
PyTorch, `datasets` and `webdataset`:

    loaders_check.py torch|hub FOLDER SHARDS REFS

FOLDER is a rendered dataset, SHARDS its WebDataset export (one sample per shard, splits train and
val, with its dataset card), REFS the Rust reader's arrays of every sample as `<id>_<array>.npy`.

torch: `stereogen.torch.StereoWebDataset` (the train and val splits) and `StereoDataset` (the
folder) through a `DataLoader` with two workers: every sample once, every tensor bit for bit the
Rust reader's (the maps too, where REFS has them, and no map key where it has none), both workers
used; then three optimiser steps of a small network on each.

hub: the code blocks of the dataset card, as they are: `datasets`' WebDataset builder (images and
the card's two lines for the disparity EXRs), then `webdataset` + a `DataLoader` with two workers.
"""

import os
import pathlib
import re
import sys

import numpy as np
import torch

import stereogen
import stereogen.torch as st

MODE, FOLDER, SHARDS, REFS = sys.argv[1], *map(pathlib.Path, sys.argv[2:5])


def ref_ids():
    """The samples REFS holds arrays of (each has `<id>_disp.npy`)."""
    return sorted(p.name[: -len("_disp.npy")] for p in REFS.glob("*_disp.npy"))


def ref(sample_id, name):
    return np.load(REFS / f"{sample_id}_{name}.npy")


def expect_tensors(sample_id, left, right, disp, valid, disp_right=None, valid_right=None):
    """The tensors of one sample against the Rust reader's arrays, bit for bit."""
    want_left = torch.from_numpy(ref(sample_id, "left")).permute(2, 0, 1)
    want_right = torch.from_numpy(ref(sample_id, "right")).permute(2, 0, 1)
    assert left.dtype == torch.float32 and left.shape == want_left.shape, (sample_id, left.shape)
    assert torch.equal(left, want_left), f"{sample_id}: left"
    assert torch.equal(right, want_right), f"{sample_id}: right"
    d = ref(sample_id, "disp")
    assert disp.dtype == torch.float32 and tuple(disp.shape) == (1, *d.shape), disp.shape
    # Bit for bit: the float32 patterns, not a tolerance.
    assert np.array_equal(disp[0].numpy().view(np.uint32), d.view(np.uint32)), f"{sample_id}: disp"
    assert valid.dtype == torch.bool
    assert np.array_equal(valid[0].numpy(), ref(sample_id, "valid") != 0), f"{sample_id}: valid"
    if disp_right is not None:
        dr = ref(sample_id, "disp_right")
        assert np.array_equal(disp_right[0].numpy().view(np.uint32), dr.view(np.uint32))
        assert np.array_equal(valid_right[0].numpy(), ref(sample_id, "valid_right") != 0)


MAP_NAMES = tuple(f"{k}_{v}" for k in ("depth", "normals", "instance", "semantic") for v in ("left", "right"))


def ref_maps(sample_id):
    """The maps the Rust reader found for the sample (those written into REFS)."""
    return sorted(n for n in MAP_NAMES if (REFS / f"{sample_id}_{n}.npy").exists())


def expect_maps(sample_id, batch, k):
    """The sample's map tensors against the Rust reader's, bit for bit; no map key it lacks."""
    names = ref_maps(sample_id)
    assert sorted(n for n in MAP_NAMES if n in batch) == names, (sample_id, names, list(batch))
    for n in names:
        t, want = batch[n][k], ref(sample_id, n)
        if n.startswith("normals_"):
            assert t.dtype == torch.float32 and tuple(t.shape) == (3, *want.shape[:2]), (n, t.shape)
            got = t.permute(1, 2, 0).contiguous().numpy()
        elif n.startswith("depth_"):
            assert t.dtype == torch.float32 and tuple(t.shape) == (1, *want.shape), (n, t.shape)
            got = t[0].numpy()
        else:
            assert t.dtype == torch.int32 and tuple(t.shape) == (1, *want.shape), (n, t.shape)
            got = t[0].numpy().astype(np.float32)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), f"{sample_id}: {n}"
    return names


def with_worker(sample):
    info = torch.utils.data.get_worker_info()
    sample["worker"] = -1 if info is None else info.id
    return sample


def every_sample_equal(data, name):
    loader = torch.utils.data.DataLoader(data, batch_size=2, num_workers=2)
    seen, workers, maps = [], set(), set()
    for batch in loader:
        for k, sample_id in enumerate(batch["id"]):
            seen.append(sample_id)
            workers.add(int(batch["worker"][k]))
            maps.update(expect_maps(sample_id, batch, k))
            expect_tensors(
                sample_id,
                batch["left"][k],
                batch["right"][k],
                batch["disp"][k],
                batch["valid"][k],
                batch["disp_right"][k],
                batch["valid_right"][k],
            )
    ids = ref_ids()
    assert sorted(seen) == ids, (name, sorted(seen), ids)
    print(f"{name}: {len(seen)} samples, bit-equal, workers {sorted(workers)}, maps: {', '.join(sorted(maps)) or 'none'}")


def three_steps(data, name):
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Conv2d(6, 8, 3, padding=1), torch.nn.ReLU(), torch.nn.Conv2d(8, 1, 3, padding=1)
    )
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    loader = torch.utils.data.DataLoader(data, batch_size=2, num_workers=2)
    losses = []
    for step, batch in zip(range(3), loader):
        pred = net(torch.cat([batch["left"], batch["right"]], 1) / 255)
        loss = (pred - batch["disp"]).abs()[batch["valid"]].mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert len(losses) == 3 and all(np.isfinite(losses)), losses
    print(f"trained 3 steps on {name}: losses {', '.join(f'{x:.3f}' for x in losses)}")


def torch_mode():
    shards = st.StereoWebDataset(SHARDS, split=["train", "val"], right=True, transform=with_worker)
    assert len(shards) == len(ref_ids())
    # Split across workers the WebDataset way: worker w of n reads shards w, w + n, ...
    assert len(shards.shards) >= 2
    every_sample_equal(shards, "StereoWebDataset")
    folder = st.StereoDataset(FOLDER, right=True, transform=with_worker)
    every_sample_equal(folder, "StereoDataset")
    by_seeking = st.StereoDataset(SHARDS, right=True, transform=with_worker)
    every_sample_equal(by_seeking, "StereoDataset over the shards")
    shuffled = st.StereoWebDataset(SHARDS, split=["train", "val"], shuffle_shards=True, shuffle_buffer=4)
    three_steps(shuffled, "StereoWebDataset")
    three_steps(st.StereoDataset(FOLDER), "StereoDataset")


def card_blocks():
    card = (SHARDS / "README.md").read_text()
    return re.findall(r"```python\n(.*?)```", card, flags=re.S)


def hub_mode():
    os.chdir(SHARDS)  # the card's loaders run in the folder of the shards
    load, decode, wds_loader, ours = card_blocks()
    ns = {}
    exec(load, ns)
    ds = ns["ds"]
    rows = 0
    for split in ds:
        for row in ds[split]:
            sample_id = row["json"]["id"]
            left = np.asarray(row["left.png"].convert("RGB"), dtype=np.float32)
            right = np.asarray(row["right.png"].convert("RGB"), dtype=np.float32)
            assert np.array_equal(left, ref(sample_id, "left")), sample_id
            assert np.array_equal(right, ref(sample_id, "right")), sample_id
            assert isinstance(row["disp_left.exr"], bytes), "the builder decodes no EXR"
            ns["row"] = row
            exec(decode, ns)
            disp, valid = ns["disp"], ns["valid"]
            assert np.array_equal(disp.view(np.uint32), ref(sample_id, "disp").view(np.uint32))
            assert np.array_equal(valid, ref(sample_id, "valid") != 0)
            assert row["json"]["manifest"]["id"] == sample_id
            rows += 1
    assert rows == len(ref_ids()), rows
    print(f"datasets: {rows} rows, images and disparities equal the Rust reader's")
    exec(wds_loader, ns)
    seen = []
    for batch in ns["loader"]:
        for k, sample_id in enumerate(batch["id"]):
            expect_tensors(sample_id, batch["left"][k], batch["right"][k], batch["disp"][k], batch["valid"][k])
            seen.append(sample_id)
    assert len(seen) == len(set(seen)) == 4, seen
    print(f"webdataset: {len(seen)} samples through 2 workers, equal the Rust reader's")
    exec(ours, ns)
    assert len(ns["by_index"]) == rows and len(list(ns["stream"])) == 4


{"torch": torch_mode, "hub": hub_mode}[MODE]()
