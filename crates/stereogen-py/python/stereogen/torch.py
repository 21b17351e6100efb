"""PyTorch datasets over stereo data, decoded by stereogen's Rust readers.

Needs PyTorch: ``pip install "stereogen[torch]"`` (or any torch >= 2.1 already installed).

:class:`StereoDataset` is a map-style dataset over any layout :func:`stereogen.open_dataset`
reads (ours, a farm's merged output, a WebDataset export read by seeking, CREStereo, SceneFlow,
Middlebury, ETH3D, KITTI, Sintel, Falling Things, InStereo2K). :class:`StereoWebDataset` is an
``IterableDataset`` that streams WebDataset shards front to back, split across distributed ranks
and ``DataLoader`` workers the way the ``webdataset`` package splits them (each rank takes every
``world_size``-th shard, each worker every ``num_workers``-th of those).

Both yield the same dict per sample:

``left``, ``right``
    float32 tensors 3 x H x W, RGB, the 8-bit values 0..255 as stored (no scaling);
``disp``
    float32 1 x H x W, the left view's disparity in pixels, 0 where there is no ground truth;
``valid``
    bool 1 x H x W, where ``disp`` holds ground truth;
``disp_right``, ``valid_right``
    the same for the right view, with ``right=True`` (a sample without one raises);
``id``
    the sample's name (str);
``depth_left``, ``normals_left``, ``instance_left``, ``semantic_left``
    the maps a sample has beside its disparity (a dataset of ours made with ``[render] outputs``,
    or its export), each where the sample has it: depth float32 1 x H x W (metres along the
    optical axis, 0 = no surface), normals float32 3 x H x W (unit, camera frame: x right, y
    down, z forward; 0 = no surface), instance and semantic ids int32 1 x H x W (the files' 16-bit
    values; 0 = no surface). With ``right=True`` also the right view's (``depth_right``, ...).
    The instance table and the class names are in :mod:`stereogen`'s sample dict
    (``instances``) and ``stereogen.open_dataset(root).semantic_classes``.

A sample's maps lie on the disparity's pixel grid: a ``transform`` that crops or flips the
disparity must do the same to every key of :data:`MAP_KEYS` the sample has.

``transform``, if given, is called on that dict and its result is returned instead.
"""

from __future__ import annotations

import json
import os
import random
import re
import tarfile
from pathlib import Path
from typing import Callable, Iterator, Optional, Sequence, Union

import numpy as np

try:
    import torch
    from torch.utils.data import Dataset, IterableDataset, get_worker_info
except ImportError as e:  # pragma: no cover - exercised by the wheel test without torch
    raise ImportError(
        "stereogen.torch needs PyTorch: pip install 'stereogen[torch]' (or install torch)"
    ) from e

import stereogen

__all__ = ["MAP_KEYS", "StereoDataset", "StereoWebDataset", "to_tensors"]

#: The keys a sample's maps take in :func:`to_tensors`' dict (left view, then right view).
MAP_KEYS = tuple(
    f"{kind}_{view}" for view in ("left", "right") for kind in ("depth", "normals", "instance", "semantic")
)

PathLike = Union[str, os.PathLike]


def to_tensors(sample: dict, right: bool = False) -> dict:
    """A sample dict of :mod:`stereogen` (NumPy arrays) as the tensors described above."""

    def image(a: np.ndarray) -> "torch.Tensor":
        return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1))).float()

    out = {
        "left": image(sample["left"]),
        "right": image(sample["right"]),
        "disp": torch.from_numpy(sample["disp_left"])[None],
        "valid": torch.from_numpy(sample["valid_left"])[None],
        "id": sample["meta"]["id"],
    }
    if right:
        if sample["disp_right"] is None:
            raise ValueError(f"sample {out['id']} has no right-view disparity (right=True)")
        out["disp_right"] = torch.from_numpy(sample["disp_right"])[None]
        out["valid_right"] = torch.from_numpy(sample["valid_right"])[None]
    for key in MAP_KEYS:
        a = sample.get(key)
        if a is None or (key.endswith("_right") and not right):
            continue
        if key.startswith("normals_"):
            out[key] = image(a)
        elif key.startswith("depth_"):
            out[key] = torch.from_numpy(a)[None]
        else:  # 16-bit ids: int32 holds them on every torch version
            out[key] = torch.from_numpy(a.astype(np.int32))[None]
    return out


class StereoDataset(Dataset):
    """Map-style dataset over any layout :func:`stereogen.open_dataset` reads.

    Each process (every ``DataLoader`` worker) opens the folder itself on first use, so the
    dataset can be handed to workers however they are started (fork, spawn, forkserver).
    """

    def __init__(
        self,
        root: PathLike,
        format: Optional[str] = None,
        right: bool = False,
        transform: Optional[Callable[[dict], object]] = None,
    ):
        self.root = os.fspath(root)
        self.format = format
        self.right = right
        self.transform = transform
        self._opened = None
        self._len = len(self._dataset())

    def _dataset(self) -> "stereogen.Dataset":
        if self._opened is None or self._opened[0] != os.getpid():
            self._opened = (os.getpid(), stereogen.open_dataset(self.root, self.format))
        return self._opened[1]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_opened"] = None
        return state

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, index: int):
        sample = to_tensors(self._dataset()[index], self.right)
        return self.transform(sample) if self.transform else sample


# webdataset's rule: the key is a member's name up to the first dot of its last path component.
_KEY = re.compile(r"^((?:.*/|)[^./]+)\.([^/]*)$")


def _shard_samples(path: str) -> Iterator[tuple]:
    """(key, {suffix: bytes}) of each sample of a tar shard, read front to back."""
    key, members = None, {}
    with tarfile.open(path, mode="r|") as tar:
        for info in tar:
            if not info.isfile():
                continue
            m = _KEY.match(info.name)
            if m is None:
                continue
            if key is not None and m.group(1) != key:
                yield key, members
                members = {}
            key = m.group(1)
            members[m.group(2)] = tar.extractfile(info).read()
    if key is not None:
        yield key, members


def _index_shards(root: Path, splits: Optional[Sequence[str]]) -> list:
    """(shard path, samples) of the named splits of an export (every split if None)."""
    indexes = sorted(root.glob("*.index.json"))
    if not indexes:
        raise ValueError(f"{root}: no <split>.index.json: not a finished WebDataset export")
    by_split = {p.name[: -len(".index.json")]: p for p in indexes}
    names = sorted(by_split) if splits is None else list(splits)
    shards = []
    for name in names:
        if name not in by_split:
            raise ValueError(f"{root}: no split {name!r} (it has {', '.join(sorted(by_split))})")
        index = json.loads(by_split[name].read_text())
        for shard in index["shards"]:
            path = root / shard["name"]
            size = path.stat().st_size if path.is_file() else None
            if size != shard["bytes"]:
                raise ValueError(
                    f"{path}: missing or not {shard['bytes']} bytes as its index says (cut short?)"
                )
            shards.append((os.fspath(path), int(shard["samples"])))
    return shards


class StereoWebDataset(IterableDataset):
    """Streams WebDataset shards (``stereogen export --format webdataset``, ``merge
    --webdataset``) front to back, each shard one sequential read.

    ``source`` is an export folder (its ``<split>.index.json`` list the shards; ``split`` names
    one split or several, default every split) or a list of ``.tar`` paths. Shards are dealt to
    distributed ranks (``torch.distributed`` when initialised) and then to ``DataLoader``
    workers: each takes every n-th shard, as ``webdataset.split_by_node`` and
    ``split_by_worker`` do, so give at least as many shards as ranks x workers.
    ``shuffle_shards`` permutes the shard list each epoch from ``seed`` and the epoch
    (:meth:`set_epoch`); ``shuffle_buffer`` > 0 shuffles samples through a buffer of that many
    (webdataset's ``shuffle``). With neither, samples come in stored order.
    """

    def __init__(
        self,
        source: Union[PathLike, Sequence[PathLike]],
        split: Union[None, str, Sequence[str]] = None,
        shuffle_shards: bool = False,
        shuffle_buffer: int = 0,
        seed: int = 0,
        right: bool = False,
        transform: Optional[Callable[[dict], object]] = None,
    ):
        if isinstance(source, (str, os.PathLike)) and Path(source).is_dir():
            splits = [split] if isinstance(split, str) else split
            shards = _index_shards(Path(source), splits)
            self.shards = [p for p, _ in shards]
            self._len = sum(n for _, n in shards)
        else:
            paths = [source] if isinstance(source, (str, os.PathLike)) else list(source)
            self.shards = [os.fspath(p) for p in paths]
            self._len = None
        self.shuffle_shards = shuffle_shards
        self.shuffle_buffer = shuffle_buffer
        self.seed = seed
        self.epoch = 0
        self.right = right
        self.transform = transform

    def set_epoch(self, epoch: int) -> None:
        """The epoch whose shard permutation and sample shuffle to use."""
        self.epoch = epoch

    def __len__(self) -> int:
        if self._len is None:
            raise TypeError("the length of a list of shards is unknown (open the export folder)")
        return self._len

    def shards_for_this_worker(self) -> list:
        """The shards this process reads: this rank's share, then this worker's share of it."""
        shards = list(self.shards)
        if self.shuffle_shards:
            random.Random(f"{self.seed}/{self.epoch}").shuffle(shards)
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            rank, world = torch.distributed.get_rank(), torch.distributed.get_world_size()
            shards = shards[rank::world]
        worker = get_worker_info()
        if worker is not None:
            shards = shards[worker.id :: worker.num_workers]
        return shards

    def _samples(self) -> Iterator[dict]:
        for path in self.shards_for_this_worker():
            for key, members in _shard_samples(path):
                members["__url__"] = path
                yield to_tensors(stereogen.decode_sample(members, key), self.right)

    def __iter__(self) -> Iterator[object]:
        samples = self._samples()
        if self.shuffle_buffer > 0:
            worker = get_worker_info()
            rng = random.Random(f"{self.seed}/{self.epoch}/{worker.id if worker else 0}")
            samples = _shuffled(samples, self.shuffle_buffer, rng)
        for sample in samples:
            yield self.transform(sample) if self.transform else sample


def _shuffled(items: Iterator[dict], size: int, rng: random.Random) -> Iterator[dict]:
    """webdataset's shuffle: a buffer of `size` items, each output drawn from it at random."""
    buffer = []
    for item in items:
        buffer.append(item)
        if len(buffer) >= size:
            k = rng.randrange(len(buffer))
            buffer[k], buffer[-1] = buffer[-1], buffer[k]
            yield buffer.pop()
    rng.shuffle(buffer)
    yield from buffer
