"""stereogen: stereo datasets as NumPy arrays, disparity files and scene planning, through the
same Rust readers the generator and the trainer use.

    ds = stereogen.open_dataset("data/")   # any layout: ours, a WebDataset export, KITTI, ...
    s = ds[0]                              # left/right uint8 HxWx3, disp_left float32 HxW, ...

PyTorch datasets (``pip install "stereogen[torch]"``) are in :mod:`stereogen.torch`.
"""

from ._stereogen import (
    Dataset,
    __version__,
    decode_disparity,
    decode_sample,
    detect_format,
    open_dataset,
    plan_scene,
    read_disparity,
    read_failures,
    read_skipped_assets,
    write_disparity,
)

__all__ = [
    "Dataset",
    "__version__",
    "decode_disparity",
    "decode_sample",
    "detect_format",
    "open_dataset",
    "plan_scene",
    "read_disparity",
    "read_failures",
    "read_skipped_assets",
    "write_disparity",
]
