"""pytest for the `stereogen` module on a WebDataset export, driven by
tests/integration/export_webdataset.rs.

That test renders a dataset with the real CLI, exports it with `stereogen export --format
webdataset` and names both folders in the JSON file at $STEREOGEN_PY_WEBDATASET. The module must
open the export the way it opens the source: the same samples (by id), the same arrays. Where the
fixture says `"maps": true` the dataset was rendered with every map (`[render] outputs`): they
read back unchanged from the folder, from the shards and from streamed members, and agree with
the disparity (`disp == f_px * baseline / depth` where valid) and the instance table; without
maps a sample dict holds no map key, as before maps existed.
Skipped when run without that fixture (tests/integration/io_python.rs runs the rest of this folder).
"""

import json
import os
import pathlib
import tarfile

import numpy as np
import pytest

import stereogen

if "STEREOGEN_PY_WEBDATASET" not in os.environ:
    pytest.skip("run by tests/integration/export_webdataset.rs", allow_module_level=True)

FIX = json.loads(pathlib.Path(os.environ["STEREOGEN_PY_WEBDATASET"]).read_text())
ARRAYS = ["left", "right", "disp_left", "valid_left", "disp_right", "valid_right"]
MAPS = {
    f"{kind}_{view}": dtype
    for kind, dtype in [("depth", np.float32), ("normals", np.float32), ("instance", np.uint16), ("semantic", np.uint16)]
    for view in ("left", "right")
}
WITH_MAPS = FIX.get("maps", False)


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
        for key, dtype in MAPS.items():
            if not WITH_MAPS:
                assert key not in want and key not in got, key
                continue
            assert got[key].dtype == want[key].dtype == dtype, key
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{sample_id}.{key}")
        assert got.get("instances") == want.get("instances")
        assert ("instances" in want) == WITH_MAPS
        for key in ["format", "f_px", "baseline_m", "cx", "cy"]:
            assert got["meta"][key] == want["meta"][key], key
        assert got["meta"]["extra"]["category"] == want["meta"]["extra"]["category"]
    # Iteration stops at the end, as for any dataset.
    assert sum(1 for _ in wds) == len(wds)


def _streamed(export):
    """(key, members) of every sample of the export's shards, read with tarfile as a loader does."""
    for shard in sorted(pathlib.Path(export).glob("*.tar")):
        samples = {}
        with tarfile.open(shard) as tar:
            for info in tar:
                key, suffix = info.name.split(".", 1)
                samples.setdefault(key, {"__url__": str(shard)})[suffix] = tar.extractfile(info).read()
        yield from samples.items()


def test_streamed_members_decode_to_the_same_maps():
    wds = stereogen.open_dataset(FIX["export"])
    by_id = {wds[i]["meta"]["id"]: wds[i] for i in range(len(wds))}
    seen = 0
    for key, members in _streamed(FIX["export"]):
        got = stereogen.decode_sample(members, key)
        want = by_id[got["meta"]["id"]]
        assert sorted(k for k in got if k in MAPS) == sorted(k for k in want if k in MAPS)
        assert [m for m in members if m.split(".")[0] in MAPS] == (
            [f"{k}.{'exr' if k.startswith(('depth', 'normals')) else 'png'}" for k in MAPS] if WITH_MAPS else []
        )
        for k in MAPS:
            if k in want:
                np.testing.assert_array_equal(got[k], want[k], err_msg=f"{key}.{k}")
        assert got.get("instances") == want.get("instances")
        seen += 1
    assert seen == FIX["len"]


def test_maps_agree_with_the_disparity_and_the_tables():
    src = stereogen.open_dataset(FIX["source"])
    classes = src.semantic_classes
    info = json.loads((pathlib.Path(FIX["source"]) / "dataset.json").read_text())
    assert classes == {c["id"]: c["name"] for c in info.get("semantic_classes", [])}
    assert bool(classes) == WITH_MAPS
    assert stereogen.open_dataset(FIX["export"]).semantic_classes == classes
    if not WITH_MAPS:
        return
    for i in range(len(src)):
        s = src[i]
        f_px, baseline = s["meta"]["f_px"], s["meta"]["baseline_m"]
        table = {r["id"]: r for r in s["instances"]}
        assert table and all(r["semantic"] in classes for r in table.values())
        for view in ("left", "right"):
            disp, valid = s[f"disp_{view}"], s[f"valid_{view}"]
            depth, normals = s[f"depth_{view}"], s[f"normals_{view}"]
            inst, sem = s[f"instance_{view}"], s[f"semantic_{view}"]
            assert depth.shape == disp.shape and normals.shape == disp.shape + (3,)
            assert inst.shape == sem.shape == disp.shape
            assert valid.any()
            # The law the disparity was made by, from the depth map: f64, then float32.
            want = (f_px * baseline / depth[valid].astype(np.float64)).astype(np.float32)
            np.testing.assert_array_equal(disp[valid], want, err_msg=f"{i} {view}")
            n = normals[valid].astype(np.float64)
            np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
            assert (inst[valid] > 0).all() and (sem[valid] > 0).all()
            # No surface: zero everywhere.
            none = depth == 0
            assert not valid[none].any()
            assert (normals[none] == 0).all() and (inst[none] == 0).all() and (sem[none] == 0).all()
            # Each pixel's class is its object's, by the instance table.
            hit = inst > 0
            assert set(np.unique(inst[hit]).tolist()) <= set(table)
            classes_of = np.zeros(int(inst.max()) + 1, np.uint16)
            for r in table.values():
                classes_of[r["id"]] = r["semantic"]
            np.testing.assert_array_equal(sem[hit], classes_of[inst[hit]])
