//! `stereogen export --format webdataset` with the real CLI: a rendered dataset of ours as tar
//! shards read back equal to the source (its EXRs byte for byte), and an export killed with
//! SIGKILL mid-way that a re-run of the same command finishes to the bytes of a clean export.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use stereo_io::{DatasetFormat, ImageEncoding, WritableFormat, create_writer, open_dataset};
use stereogen_e2e::export_cmd;

fn export(data: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = export_cmd(data, "webdataset", out);
    c.args(extra);
    c
}

fn run(c: &mut Command) -> String {
    let out = c.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    stderr
}

/// Every file of a folder, with its bytes, sorted by name.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    out.sort();
    out
}

#[test]
fn a_rendered_dataset_as_shards_reads_back_as_it_was() {
    let t = tempfile::tempdir().unwrap();
    let ours = stereogen_e2e::generate_tiny_dataset(t.path(), "ours", 3, 7);
    let shards = t.path().join("shards");
    let said = run(&mut export(
        &ours,
        &shards,
        &["--shard-size", "1B", "--splits", "train=0.67,val=0.33"],
    ));
    assert!(
        said.contains("exported 3 sample(s) as 3 WebDataset shard(s)"),
        "{said}"
    );
    for name in [
        "train.index.json",
        "val.index.json",
        "dataset.json",
        "train-000000.tar",
    ] {
        assert!(shards.join(name).is_file(), "{name}");
    }
    let source = open_dataset(&ours, None).unwrap();
    let read = open_dataset(&shards, None).unwrap();
    assert_eq!((read.format(), read.len()), (DatasetFormat::WebDataset, 3));
    for i in 0..3 {
        let got = read.sample(i).unwrap();
        let k = (0..3)
            .find(|&k| source.sample(k).unwrap().meta.id == got.meta.id)
            .expect("a sample of the source");
        let want = source.sample(k).unwrap();
        assert_eq!((got.left, got.right), (want.left, want.right));
        assert_eq!(got.disp_left, want.disp_left);
        assert_eq!(got.disp_right, want.disp_right);
        assert_eq!(
            got.meta.extra.get("category"),
            want.meta.extra.get("category")
        );
    }
    // An existing export is kept unless --force.
    let refused = export(&ours, &shards, &[]).output().unwrap();
    let e = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && e.contains("--force"), "{e}");
    run(&mut export(&ours, &shards, &["--force"]));
}

/// A dataset that takes the export a few seconds: CREStereo's layout, written directly.
fn many_samples(root: &Path, n: usize) -> PathBuf {
    let mut w = create_writer(WritableFormat::Crestereo, root, ImageEncoding::Lossless).unwrap();
    let (width, height) = (320, 240);
    for k in 0..n {
        let noise = |salt: usize| -> Vec<u8> {
            (0..width * height * 3)
                .map(|i| ((i * 2_654_435_761 + k * 97 + salt) >> 7) as u8)
                .collect()
        };
        let image = |salt| stereo_io::RgbImage {
            width,
            height,
            data: noise(salt),
        };
        let mut disp = stereo_io::DisparityMap::new(width, height);
        disp.data
            .iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = (i % 97) as f32 * 0.5);
        disp.valid.fill(true);
        let sample = stereo_io::StereoSample {
            left: image(1),
            right: image(2),
            disp_left: disp.clone(),
            disp_right: Some(disp),
            valid_left: None,
            meta: Default::default(),
        };
        w.write(k, &format!("{}/{k:07}", ["tree", "hole"][k % 2]), &sample)
            .unwrap();
    }
    root.to_path_buf()
}

#[test]
fn an_export_killed_mid_way_is_finished_by_the_same_command() {
    let t = tempfile::tempdir().unwrap();
    let source = many_samples(&t.path().join("source"), 120);
    let args = ["--shard-size", "2MiB", "--shuffle-seed", "5"];
    let clean = t.path().join("clean");
    run(&mut export(&source, &clean, &args));

    let out = t.path().join("killed");
    let mut child = export(&source, &out, &args)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let shard = |n: usize| out.join(format!("train-{n:06}.tar"));
    while !shard(1).exists() && start.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL: no chance to clean up
    child.wait().unwrap();
    assert!(shard(1).exists(), "two shards written before the kill");
    assert!(
        !out.join("train.index.json").exists(),
        "killed before the end"
    );
    let e = open_dataset(&out, None)
        .err()
        .expect("an unfinished export is no dataset")
        .to_string();
    assert!(e.contains("unfinished WebDataset export"), "{e}");

    let said = run(&mut export(&source, &out, &args));
    assert!(!said.contains("(0 kept from an interrupted run)"), "{said}");
    assert!(
        files(&out) == files(&clean),
        "the resumed export differs from a clean one"
    );
}
