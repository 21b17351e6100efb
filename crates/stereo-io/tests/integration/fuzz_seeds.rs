//! The fuzzers' seed corpus (`fuzz/corpus/<target>/`) is real files, made by our own writers, that
//! each fuzzed reader accepts: a fuzzer that starts from files its reader refuses explores little
//! past the first check. `STEREO_IO_WRITE_FUZZ_SEEDS=1` writes the seeds anew from the writers
//! before checking them (after a format change).

use std::fs;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use stereo_io::datasets::stereogen::{
    FailureRecord, SkippedAssetRecord, read_manifest_from, read_sidecar_from,
};
use stereo_io::datasets::webdataset::{ShardIndex, scan_tar};
use stereo_io::pth::{NamedArray, check_state_dict_from, encode_state_dict};
use stereo_io::*;

use crate::io_fixtures;
use io_fixtures::*;

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus")
}

/// Writes every seed from our writers.
fn write_seeds() {
    let dir = tempfile::tempdir().unwrap();
    let put = |target: &str, name: &str, bytes: &[u8]| {
        let d = mkdir(&corpus().join(target));
        fs::write(d.join(name), bytes).unwrap();
    };
    // A real export's first shard (two samples) and the index that names just it.
    let source = mkdir(&dir.path().join("source"));
    our_dataset(&source);
    let out = dir.path().join("wds");
    let opts = WebDatasetOptions {
        shard_bytes: 6000,
        ..Default::default()
    };
    export_webdataset(&source, &out, None, &ReadOptions::default(), &opts).unwrap();
    let shard = fs::read(out.join("train-000000.tar")).unwrap();
    let samples = WebDataset::open(&out).unwrap().shard_samples()[0];
    put("tar_shard", "export.tar", &shard);
    let index = format!(
        r#"{{"format":"stereogen-webdataset","version":1,"split":"train","samples":{samples},"shards":[{{"name":"train-000000.tar","samples":{samples},"bytes":{}}}]}}"#,
        shard.len()
    );
    put("webdataset_index", "train.index.json", index.as_bytes());
    // State dicts: stored as torch.save writes them, and re-zipped with deflate.
    let tensors = [("enc.weight", vec![4, 3, 3, 3]), ("enc.bias", vec![4])].map(|(n, s)| {
        let count: usize = s.iter().product();
        NamedArray {
            name: n.into(),
            shape: s,
            data: (0..count).map(|i| i as f32 / 7.0).collect(),
        }
    });
    let stored = encode_state_dict(&tensors).unwrap();
    put("pth", "stored.pth", &stored);
    put("pth", "deflated.pth", &deflated(&stored));
    // Disparity files as the generator and the exporters write them.
    let meta = left_view_meta(64.0, 0.1);
    let exr = dir.path().join("d.exr");
    write_disparity_exr(&exr, &disp(2.0), &meta).unwrap();
    put("exr_disparity", "disp.exr", &fs::read(&exr).unwrap());
    let png = dir.path().join("d.png");
    write_disparity_png16(&png, &disp(2.0), 256.0).unwrap();
    put("png_disparity", "disp.png", &fs::read(&png).unwrap());
    let jpg = dir.path().join("p.jpg");
    write_jpeg_rgb(&jpg, &rgb(3), 90).unwrap();
    put("png_disparity", "photo.jpg", &fs::read(&jpg).unwrap());
    // Our JSON-lines logs.
    let manifest = fs::read_to_string(source.join("manifest.jsonl")).unwrap();
    let two: String = manifest.lines().take(2).map(|l| format!("{l}\n")).collect();
    put("json_lines", "manifest.jsonl", two.as_bytes());
    let failure = FailureRecord::new(3, "worker crashed", Some("Traceback ...".into()));
    let skipped = SkippedAssetRecord::new("/meshes/a.obj", "no triangles", Some(4));
    let lines = format!(
        "{}\n{}\n",
        serde_json::to_string(&failure).unwrap(),
        serde_json::to_string(&failure).unwrap()
    );
    put("json_lines", "failures.jsonl", lines.as_bytes());
    let line = serde_json::to_string(&skipped).unwrap() + "\n";
    put("json_lines", "skipped_assets.jsonl", line.as_bytes());
}

fn deflated(stored: &[u8]) -> Vec<u8> {
    use std::io::{Read, Write};
    let mut from = zip::ZipArchive::new(Cursor::new(stored)).unwrap();
    let mut to = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let options =
        zip::write::SimpleFileOptions::DEFAULT.compression_method(zip::CompressionMethod::Deflated);
    for i in 0..from.len() {
        let mut e = from.by_index(i).unwrap();
        let mut data = Vec::new();
        e.read_to_end(&mut data).unwrap();
        to.start_file(e.name(), options).unwrap();
        to.write_all(&data).unwrap();
    }
    to.finish().unwrap().into_inner()
}

fn seeds(target: &str) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<_> = fs::read_dir(corpus().join(target))
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                fs::read(&p).unwrap(),
            )
        })
        .collect();
    out.sort();
    assert!(!out.is_empty(), "no seeds for {target}");
    out
}

#[test]
fn every_seed_is_a_file_its_reader_accepts() {
    if std::env::var_os("STEREO_IO_WRITE_FUZZ_SEEDS").is_some() {
        write_seeds();
    }
    let p = Path::new("seed");
    for (name, bytes) in seeds("tar_shard") {
        let members = scan_tar(Cursor::new(&bytes), bytes.len() as u64, p).unwrap();
        assert!(members.len() >= 5, "{name}: a whole sample at least");
    }
    for (name, bytes) in seeds("webdataset_index") {
        let index = ShardIndex::parse(&bytes, p).unwrap();
        assert_eq!(index.shards.len(), 1, "{name}: the tar_shard seed");
    }
    for (name, bytes) in seeds("pth") {
        let listed = check_state_dict_from(Cursor::new(&bytes), bytes.len() as u64, p).unwrap();
        assert_eq!(listed.len(), 2, "{name}");
    }
    for (_, bytes) in seeds("exr_disparity") {
        decode_disparity_exr(&bytes, p).unwrap();
    }
    for (name, bytes) in seeds("png_disparity") {
        match name.ends_with(".png") {
            true => drop(decode_disparity_png16(&bytes, p, 256.0).unwrap()),
            false => drop(decode_jpeg(&bytes, p).unwrap()),
        }
    }
    for (name, bytes) in seeds("json_lines") {
        let ok = match name.as_str() {
            "manifest.jsonl" => read_manifest_from(&bytes[..], p).unwrap().entries.len(),
            "failures.jsonl" => read_sidecar_from::<FailureRecord>(&bytes[..], p)
                .unwrap()
                .records
                .len(),
            _ => read_sidecar_from::<SkippedAssetRecord>(&bytes[..], p)
                .unwrap()
                .records
                .len(),
        };
        assert!(ok > 0, "{name}");
    }
}

/// Inputs that once failed a fuzzer (`fuzz/regressions/exr_disparity/`), decoded by the build the
/// tests run, which is the release build that ships: each is read or refused with an error that
/// names the file, never a panic. (`fuzz/run` replays them in its own instrumented build too.)
#[test]
fn exr_inputs_that_once_failed_a_fuzzer_are_read_or_refused_in_a_release_build() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/regressions/exr_disparity");
    let mut seen = 0;
    for entry in fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let bytes = fs::read(&path).unwrap();
        if let Err(e) = decode_disparity_exr(&bytes, Path::new("hostile.exr")) {
            assert!(e.to_string().contains("hostile.exr"), "{path:?}: {e}");
        }
        seen += 1;
    }
    assert!(seen >= 2, "the regression inputs are missing from {dir:?}");
}
