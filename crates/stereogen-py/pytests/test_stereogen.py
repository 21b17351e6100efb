"""pytest for the `stereogen` Python module, driven by the Rust test tests/integration/io_python.rs.

That test writes fixtures under $STEREOGEN_PY_FIXTURES, reads them with the Rust readers and
saves what they returned as .npy files (loaded here with NumPy's own reader), so every check
compares the module against Rust on the same files.
"""

import json
import os
import pathlib
import subprocess
import threading

import numpy as np
import pytest

import stereogen

FIX = pathlib.Path(os.environ["STEREOGEN_PY_FIXTURES"])
EXPECT = json.loads((FIX / "expect.json").read_text())


def ref(name):
    return np.load(FIX / "ref" / f"{name}.npy")


@pytest.mark.parametrize("name", sorted(EXPECT["datasets"]))
def test_dataset_values_equal_the_rust_readers(name):
    info = EXPECT["datasets"][name]
    ds = stereogen.open_dataset(str(FIX / name))
    assert ds.format == info["format"]
    assert len(ds) == info["len"]
    forced = stereogen.open_dataset(str(FIX / name), format=info["format"])
    assert len(forced) == len(ds)
    for i in range(len(ds)):
        s = ds[i]
        assert s["meta"]["id"] == info["ids"][i]
        for key, dtype in [("left", np.uint8), ("right", np.uint8), ("disp_left", np.float32), ("valid_left", np.bool_)]:
            want = ref(f"{name}_{i}_{key}")
            got = s[key]
            assert got.dtype == dtype, key
            assert got.shape == want.shape, key
            np.testing.assert_array_equal(got, want.astype(dtype), err_msg=f"{name}[{i}].{key}")
        assert s["left"].ndim == 3 and s["left"].shape[2] == 3
        assert s["disp_left"].flags["C_CONTIGUOUS"]
        for k, v in info["meta"].items():
            assert s["meta"][k] == pytest.approx(v), k
    # Negative indices work, too-large ones raise IndexError (so iteration stops).
    np.testing.assert_array_equal(ds[-1]["disp_left"], ds[len(ds) - 1]["disp_left"])
    with pytest.raises(IndexError):
        ds[len(ds)]
    assert sum(1 for _ in ds) == len(ds)


def test_decoding_runs_in_threads():
    """The GIL is released while decoding: threads finish and agree with serial reads."""
    ds = stereogen.open_dataset(str(FIX / "ours"))
    out = [None] * 8

    def work(k):
        out[k] = ds[k % len(ds)]["disp_left"]

    threads = [threading.Thread(target=work, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k in range(8):
        np.testing.assert_array_equal(out[k], ds[k % len(ds)]["disp_left"])


def test_read_disparity_matches_rust_and_write_round_trips(tmp_path):
    d, v, meta = stereogen.read_disparity(str(FIX / "ours" / EXPECT["exr"]), with_meta=True)
    np.testing.assert_array_equal(d, ref("exr_disp"))
    np.testing.assert_array_equal(v, ref("exr_valid").astype(bool))
    assert meta["f_px"] == pytest.approx(EXPECT["exr_f_px"])
    for ext in ["exr", "pfm", "npy"]:
        p = tmp_path / f"w.{ext}"
        arr = np.where(v, d, np.inf).astype(np.float64)  # float64 in, inf = invalid
        stereogen.write_disparity(str(p), arr, f_px=500.0, baseline=0.25)
        d2, v2 = stereogen.read_disparity(str(p))
        np.testing.assert_array_equal(v2, v)
        np.testing.assert_array_equal(d2, np.where(v, d, 0).astype(np.float32))
    # NumPy reads our .npy; inf marks invalid pixels.
    np.testing.assert_array_equal(np.isfinite(np.load(tmp_path / "w.npy")), v)
    _, _, m = stereogen.read_disparity(str(tmp_path / "w.exr"), with_meta=True)
    assert (m["f_px"], m["baseline_m"]) == (500.0, 0.25)
    # KITTI-style 16-bit PNG with an explicit mask.
    p = tmp_path / "k.png"
    stereogen.write_disparity(str(p), np.full((2, 3), 1.5, np.float32), valid=np.array([[1, 0, 1], [1, 1, 1]], bool))
    d3, v3 = stereogen.read_disparity(str(p), format="png256")
    assert d3.tolist() == [[1.5, 0, 1.5], [1.5, 1.5, 1.5]] and not v3[0, 1]


def test_errors_carry_the_rust_message():
    for case in EXPECT["errors"]:
        exc = {"ValueError": ValueError, "OSError": OSError}[case["type"]]
        with pytest.raises(exc) as e:
            if case["call"] == "read_disparity":
                stereogen.read_disparity(case["path"])
            elif case["call"] == "open_dataset":
                stereogen.open_dataset(case["path"])[0]
            elif case["call"] == "read_failures":
                stereogen.read_failures(case["path"])
        assert str(e.value) == case["message"]
    with pytest.raises(ValueError, match="unknown dataset format"):
        stereogen.open_dataset(str(FIX / "ours"), format="nope")
    with pytest.raises(ValueError, match="2-D"):
        stereogen.write_disparity(str(FIX / "x.pfm"), np.zeros((2, 2, 2)))


def test_plan_scene_equals_the_cli():
    cli = json.loads(subprocess.run([os.environ["STEREOGEN_BIN"], "plan", "--recipe", "crestereo", "--seed", "3", "--index", "1"], check=True, capture_output=True, text=True).stdout)
    assert stereogen.plan_scene("crestereo", 3, 1) == cli
    assert stereogen.plan_scene("crestereo", 3, 2) != cli
    with pytest.raises(ValueError):
        stereogen.plan_scene(str(FIX / "missing.toml"), 0, 0)


def test_sidecar_logs_read_as_the_rust_records():
    want = EXPECT["sidecars"]
    assert stereogen.read_failures(str(FIX / "ours" / "failures.jsonl")) == want["failures"]
    assert stereogen.read_skipped_assets(str(FIX / "ours" / "skipped_assets.jsonl")) == want["skipped_assets"]
    assert want["failures"][1]["traceback"].startswith("Traceback")
    assert stereogen.read_failures(str(FIX / "ours" / "no-such.jsonl")) == []
