//! The Python package as its users get it: the wheel built by the guide's one command
//! (`maturin build --release -m crates/stereogen-py/Cargo.toml --out dist`), installed into a fresh
//! venv; `stereogen.torch`'s datasets through a real `DataLoader` with two workers, on a rendered
//! dataset's WebDataset shards and on its folder, every tensor equal to the Rust reader's; and the
//! shards read by the `datasets` package's WebDataset builder and by `webdataset` + a `DataLoader`
//! with nothing but the code the dataset card shows.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Instant;

use stereo_io::{NpyArray, open_dataset, write_npy};
use test_support::export_cmd;

use python_envs::{base_venvs, fresh_venv, pinned_venv::run, python_home, repo_root, target_dir};
use test_support::python_envs;

/// The wheel, built once per test run with the guide's command into `<target>/python-wheel`
/// (by the maturin and for the Python of tests/integration/io_python.rs, in its cargo folder: one
/// build of the module serves both).
fn wheel() -> &'static PathBuf {
    static WHEEL: OnceLock<PathBuf> = OnceLock::new();
    WHEEL.get_or_init(|| {
        let maturin = python_envs::pinned_venv::ensure_venv("venv-test", python_envs::MATURIN_PINS);
        let dist = target_dir().join("python-wheel");
        let _ = std::fs::remove_dir_all(&dist);
        let t = Instant::now();
        let _turn = test_support::turns::python_ext();
        run(
            Command::new(maturin.join("bin/maturin"))
                .args(["build", "--release", "-m", "crates/stereogen-py/Cargo.toml"])
                .arg("--out")
                .arg(&dist)
                .arg("--interpreter")
                .arg(maturin.join("bin/python"))
                .current_dir(repo_root())
                .env("CARGO_TARGET_DIR", target_dir().join("python-ext"))
                // Not the nightly switch tests/run's test runner sets for libtest.
                .env_remove("RUSTC_BOOTSTRAP"),
            "maturin build --release",
        );
        let wheel = std::fs::read_dir(&dist)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.extension().is_some_and(|x| x == "whl"))
            .expect("maturin wrote a wheel");
        let bytes = std::fs::metadata(&wheel).unwrap().len();
        println!(
            "wheel {} ({:.2} MB) built in {:.1} s",
            wheel.file_name().unwrap().to_string_lossy(),
            bytes as f64 / 1e6,
            t.elapsed().as_secs_f64()
        );
        wheel
    })
}

fn python(venv: &Path, code: &str) -> std::process::Output {
    Command::new(venv.join("bin/python"))
        .args(["-c", code])
        .output()
        .unwrap()
}

#[test]
fn the_wheel_installs_into_a_fresh_venv_and_torch_is_an_extra() {
    let wheel = wheel();
    // A venv with nothing in it: the wheel and its one dependency, NumPy.
    let bare = fresh_venv(&python_home().join("wheel-test-bare"), &[]);
    install(
        pinned_venv_pip(&bare).arg(wheel).arg("numpy==2.4.6"),
        "pip install wheel + numpy",
    );
    imports(
        &bare,
        "import stereogen; print(stereogen.__version__, stereogen.open_dataset, stereogen.decode_sample)",
    );
    let no_torch = python(&bare, "import stereogen.torch");
    let err = String::from_utf8_lossy(&no_torch.stderr);
    assert!(
        !no_torch.status.success()
            && err.contains("ImportError")
            && err.contains("stereogen[torch]"),
        "without torch, `import stereogen.torch` must say which extra is missing:\n{err}"
    );
    // With the `torch` extra: pip resolves it against the PyTorch a venv already sees.
    let (torch, _) = base_venvs();
    let with_torch = fresh_venv(&python_home().join("wheel-test-torch"), &[&torch]);
    let spec = format!("{}[torch]", wheel.display());
    install(
        pinned_venv_pip(&with_torch).arg(&spec),
        "pip install wheel[torch] on torch",
    );
    imports(
        &with_torch,
        "import stereogen.torch as st; print(st.StereoDataset, st.StereoWebDataset, st.to_tensors)",
    );
}

/// Runs a `pip install` and says how long it took.
fn install(pip: &mut Command, what: &str) {
    let t = Instant::now();
    run(pip, what);
    println!("{what}: {:.1} s", t.elapsed().as_secs_f64());
}

/// Runs `code` in the venv's Python, which must succeed.
fn imports(venv: &Path, code: &str) {
    let ok = python(venv, code);
    assert!(
        ok.status.success(),
        "{code}:\n{}",
        String::from_utf8_lossy(&ok.stderr)
    );
}

fn pinned_venv_pip(venv: &Path) -> Command {
    python_envs::pinned_venv::pip_install(venv)
}

/// A rendered dataset, its WebDataset export (one sample per shard, so two workers each get
/// shards of their own; a train and a val split) and the Rust reader's arrays of every sample as
/// `.npy` files (`<id>_<array>.npy`, float32), made once for both tests below.
struct Fixture {
    _dir: tempfile::TempDir,
    folder: PathBuf,
    shards: PathBuf,
    refs: PathBuf,
}

/// A rendered dataset (6 scenes of the tiny `crestereo` mix, seed 11), its WebDataset export
/// (one sample per shard, splits train and val) and the Rust reader's arrays of every sample;
/// `with_maps`: rendered with every map a recipe can ask for, whose arrays are written too.
fn make_fixture(with_maps: bool) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let folder = if with_maps {
        let mut recipe = test_support::tiny_recipe("crestereo");
        recipe.render.outputs = stereogen::plan::OutputMap::ALL.to_vec();
        let path = dir.path().join("tiny-maps.toml");
        std::fs::write(&path, toml::to_string(&recipe).unwrap()).unwrap();
        let out = dir.path().join("ours");
        test_support::run_ok(test_support::generate_cmd(&path, &out, 6).args(["--seed", "11"]));
        out
    } else {
        test_support::generate_tiny_dataset(dir.path(), "ours", 6, 11)
    };
    let shards = dir.path().join("shards");
    let out = export_cmd(&folder, "webdataset", &shards)
        .args(["--shard-size", "1B", "--splits", "train=0.67,val=0.33"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let refs = dir.path().join("refs");
    std::fs::create_dir_all(&refs).unwrap();
    let ds = open_dataset(&folder, None).unwrap();
    for i in 0..ds.len() {
        let s = ds.sample(i).unwrap();
        let id = s.meta.id.clone();
        let (w, h) = (s.left.width, s.left.height);
        let f = |v: &[u8]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        let b = |v: &[bool]| v.iter().map(|&x| x as u8 as f32).collect::<Vec<f32>>();
        let right = s
            .disp_right
            .as_ref()
            .expect("ours have a right-view disparity");
        let valid = s.valid_mask().to_vec();
        let mut arrays = vec![
            ("left".to_string(), vec![h, w, 3], f(&s.left.data)),
            ("right".to_string(), vec![h, w, 3], f(&s.right.data)),
            ("disp".to_string(), vec![h, w], s.disp_left.data.clone()),
            ("valid".to_string(), vec![h, w], b(&valid)),
            ("disp_right".to_string(), vec![h, w], right.data.clone()),
            ("valid_right".to_string(), vec![h, w], b(&right.valid)),
        ];
        let maps = ds.maps(i).unwrap();
        assert_eq!(maps.is_empty(), !with_maps);
        for view in ["left", "right"] {
            let v = maps.view(view);
            let ids = |m: &stereo_io::IdMap| m.data.iter().map(|&x| f32::from(x)).collect();
            if let Some(m) = &v.depth {
                arrays.push((format!("depth_{view}"), vec![h, w], m.data.clone()));
            }
            if let Some(m) = &v.normals {
                let flat = m.data.iter().flatten().copied().collect();
                arrays.push((format!("normals_{view}"), vec![h, w, 3], flat));
            }
            if let Some(m) = &v.instance {
                arrays.push((format!("instance_{view}"), vec![h, w], ids(m)));
            }
            if let Some(m) = &v.semantic {
                arrays.push((format!("semantic_{view}"), vec![h, w], ids(m)));
            }
        }
        for (name, shape, data) in arrays {
            write_npy(
                &refs.join(format!("{id}_{name}.npy")),
                &NpyArray { shape, data },
            )
            .unwrap();
        }
    }
    Fixture {
        _dir: dir,
        folder,
        shards,
        refs,
    }
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| make_fixture(false))
}

/// The fixture rendered with every map.
fn fixture_with_maps() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| make_fixture(true))
}

/// Runs crates/stereogen-py/pytests/loaders_check.py `mode` on each of `fixtures` in a fresh venv
/// with the wheel (and its torch extra) on the base venvs; returns its stdout.
fn check(mode: &str, venv_name: &str, fixtures: &[&Fixture]) -> String {
    let wheel = wheel();
    let (torch, hub) = base_venvs();
    let venv = fresh_venv(&python_home().join(venv_name), &[&hub, &torch]);
    run(
        pinned_venv_pip(&venv).arg(format!("{}[torch]", wheel.display())),
        "pip install wheel[torch]",
    );
    let mut said = String::new();
    for fx in fixtures {
        let out = run(
            Command::new(venv.join("bin/python"))
                .arg(repo_root().join("crates/stereogen-py/pytests/loaders_check.py"))
                .arg(mode)
                .arg(&fx.folder)
                .arg(&fx.shards)
                .arg(&fx.refs)
                .env("HF_HUB_OFFLINE", "1")
                .env("HF_DATASETS_OFFLINE", "1")
                .env("HF_HOME", fx.refs.join(format!("hf-{mode}"))),
            &format!("loaders_check.py {mode}"),
        );
        println!("{out}");
        said += &out;
    }
    said
}

#[test]
fn torch_datasets_through_two_workers_equal_the_rust_reader() {
    let said = check(
        "torch",
        "wheel-test-loaders",
        &[fixture(), fixture_with_maps()],
    );
    for (line, times) in [
        (
            "StereoWebDataset: 6 samples, bit-equal, workers [0, 1], maps: none",
            1,
        ),
        (
            "StereoDataset: 6 samples, bit-equal, workers [0, 1], maps: none",
            1,
        ),
        (
            "StereoWebDataset: 6 samples, bit-equal, workers [0, 1], maps: depth_left, depth_right, instance_left, instance_right, normals_left, normals_right, semantic_left, semantic_right",
            1,
        ),
        (
            "StereoDataset: 6 samples, bit-equal, workers [0, 1], maps: depth_left, depth_right, instance_left, instance_right, normals_left, normals_right, semantic_left, semantic_right",
            1,
        ),
        ("trained 3 steps on StereoWebDataset", 2),
        ("trained 3 steps on StereoDataset", 2),
    ] {
        assert_eq!(said.matches(line).count(), times, "{line:?} in\n{said}");
    }
}

#[test]
fn datasets_and_webdataset_read_the_shards_as_the_card_shows() {
    let fx = fixture();
    let card = std::fs::read_to_string(fx.shards.join("README.md")).unwrap();
    assert!(card.starts_with("---\nlicense:"), "{card}");
    for needle in [
        "task_categories:\n- depth-estimation",
        "configs:\n- config_name: default",
        "  - split: train\n    path: \"train-*.tar\"",
        "  - split: val\n    path: \"val-*.tar\"",
        "| train | 4 | 4 |",
        "| val | 2 | 2 |",
        "it has no decoder for EXR",
        "disp, valid = stereogen.decode_disparity(row[\"disp_left.exr\"])",
    ] {
        assert!(card.contains(needle), "the card lacks {needle:?}:\n{card}");
    }
    let said = check("hub", "wheel-test-hub", &[fixture()]);
    for line in [
        "datasets: 6 rows, images and disparities equal the Rust reader's",
        "webdataset: 4 samples through 2 workers, equal the Rust reader's",
    ] {
        assert!(said.contains(line), "missing {line:?} in\n{said}");
    }
}
