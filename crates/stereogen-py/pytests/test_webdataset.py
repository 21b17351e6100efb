"""pytest for the `stereogen` module on a WebDataset export, driven by
tests/integration/export_webdataset.rs.

That test renders a dataset with the real CLI, exports it with `stereogen export --format
webdataset` and names both folders in the JSON file at $STEREOGEN_PY_WEBDATASET. The module must
open the export the way it opens the source: the same samples (by id), the same arrays.
Skipped when run without that fixture (tests/integration/io_python.rs runs the rest of this folder).
"""

import json
import os
import pathlib

import numpy as np
import pytest

import stereogen

if "STEREOGEN_PY_WEBDATASET" not in os.environ:
    pytest.skip("run by tests/integration/export_webdataset.rs", allow_module_level=True)

FIX = json.loads(pathlib.Path(os.environ["STEREOGEN_PY_WEBDATASET"]).read_text())
ARRAYS = ["left", "right", "disp_left", "valid_left", "disp_right", "valid_right"]


def test_an_export_reads_as_its_source():
    src = stereogen.open_dataset(FIX["source"])
    wds = stereogen.open_dataset(FIX["export"])
    assert (src.format, wds.format) == ("stereogen", "webdataset")
    assert len(wds) == len(src) == FIX["len"]
    forced = stereogen.open_dataset(FIX["export"], format="webdataset")
    assert [forced.id(i) for i in range(len(forced))] == [wds.id(i) for i in range(len(wds))]
    by_id = {src[i]["meta"]["id"]: i for i in range(len(src))}
    got_ids = [wds[i]["meta"]["id"] for i in range(len(wds))]
    assert sorted(got_ids) == sorted(by_id), "every sample once"
    for i, sample_id in enumerate(got_ids):
        got, want = wds[i], src[by_id[sample_id]]
        for key in ARRAYS:
            assert want[key] is not None, key
            assert got[key].dtype == want[key].dtype, key
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{sample_id}.{key}")
        for key in ["format", "f_px", "baseline_m", "cx", "cy"]:
            assert got["meta"][key] == want["meta"][key], key
        assert got["meta"]["extra"]["category"] == want["meta"]["extra"]["category"]
    # Iteration stops at the end, as for any dataset.
    assert sum(1 for _ in wds) == len(wds)
