//! Every other reader of bytes that travel, given files a hostile or broken copy would hold: a
//! small PNG or JPEG claiming 30000×30000 pixels, EXR/PFM/NPY headers asking for gigabytes, an
//! .npz zip bomb, a manifest line of 17 MiB or one naming a file outside the dataset, a pipe
//! where a file should be. Each is one error naming the file and the limit, refused before the
//! memory it asks for is allocated (the limits are in `stereo_io::limits`).

use std::fs;
use std::io::Write;

use stereo_io::datasets::stereogen::{FailureRecord, read_sidecar};
use stereo_io::limits::{MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE};
use stereo_io::*;

use crate::io_fixtures;
use io_fixtures::*;

fn error_of<T>(r: Result<T>, name: &str) -> String {
    let e = r.err().expect("a hostile file must be refused").to_string();
    assert!(e.contains(name) && !e.contains('\n'), "{e}");
    e
}

#[test]
fn image_bombs_are_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    // The header alone says 30000×30000: refused from it, whatever follows.
    let png = dir.path().join("bomb.png");
    write_png_claiming(&png, 30000, 30000);
    let e = error_of(read_rgb(&png), "bomb.png");
    assert!(
        e.contains("30000x30000") && e.contains("refused before decoding"),
        "{e}"
    );
    let e = error_of(read_disparity_png16(&png, 256.0), "bomb.png");
    assert!(e.contains("30000x30000"), "{e}");

    // A JPEG whose frame header claims 30000×30000.
    let jpg = dir.path().join("bomb.jpg");
    write_jpeg_rgb(&jpg, &rgb(1), 90).unwrap();
    let mut bytes = fs::read(&jpg).unwrap();
    let sof = bytes.windows(2).position(|w| w == [0xff, 0xc0]).unwrap();
    bytes[sof + 5..sof + 7].copy_from_slice(&30000u16.to_be_bytes());
    bytes[sof + 7..sof + 9].copy_from_slice(&30000u16.to_be_bytes());
    fs::write(&jpg, &bytes).unwrap();
    let e = error_of(read_rgb(&jpg), "bomb.jpg");
    assert!(e.contains("30000x30000"), "{e}");
}

#[test]
fn disparity_headers_asking_for_gigabytes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pfm = dir.path().join("big.pfm");
    fs::write(&pfm, format!("Pf\n{} 2\n-1.0\n", MAX_IMAGE_SIDE + 1)).unwrap();
    let e = error_of(read_disparity_pfm(&pfm), "big.pfm");
    assert!(e.contains("outside 1..=32768"), "{e}");
    fs::write(&pfm, "PF\n20000 20000\n-1.0\n").unwrap();
    let e = error_of(read_disparity_pfm(&pfm), "big.pfm");
    assert!(
        e.contains("20000x20000") && e.contains("over the readers' limits"),
        "{e}"
    );

    // An .npy of 2^31 bytes in its header and 10 in its body.
    let npy = dir.path().join("big.npy");
    let header = "{'descr': '|u1', 'fortran_order': False, 'shape': (65536, 32768), }";
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    bytes.extend([0u8; 10]);
    fs::write(&npy, &bytes).unwrap();
    let e = error_of(read_disparity_npy(&npy), "big.npy");
    assert!(e.contains("over the readers' limit of 1 GiB"), "{e}");

    // An EXR claiming MAX_IMAGE_PIXELS + a row, the file a few hundred bytes.
    let exr = dir.path().join("big.exr");
    write_disparity_exr(&exr, &disp(1.0), &DisparityMeta::default()).unwrap();
    let small = fs::read(&exr).unwrap();
    let side = (MAX_IMAGE_PIXELS as f64).sqrt() as i32 + 1;
    let mut bytes = small.clone();
    let window = bytes.windows(10).position(|w| w == b"dataWindow").unwrap();
    // name\0 type\0 size(4) then xMin yMin xMax yMax.
    let at = window + b"dataWindow\0box2i\0".len() + 4;
    bytes[at + 8..at + 12].copy_from_slice(&(side - 1).to_le_bytes());
    bytes[at + 12..at + 16].copy_from_slice(&(side - 1).to_le_bytes());
    fs::write(&exr, &bytes).unwrap();
    let e = error_of(read_disparity_exr(&exr), "big.exr");
    assert!(e.contains(&format!("{side}x{side}")), "{e}");
}

#[test]
fn an_npz_bomb_is_cut_off_at_the_limit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bomb.npz");
    // One array whose header says 1088 MiB of bytes, deflated from zeros (about 1 MB).
    let header = "{'descr': '|u1', 'fortran_order': False, 'shape': (1140850688,), }";
    let mut zip = zip::ZipWriter::new(fs::File::create(&path).unwrap());
    let options = zip::write::SimpleFileOptions::DEFAULT
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(true);
    zip.start_file("disp.npy", options).unwrap();
    zip.write_all(b"\x93NUMPY\x01\x00").unwrap();
    zip.write_all(&(header.len() as u16).to_le_bytes()).unwrap();
    zip.write_all(header.as_bytes()).unwrap();
    let zeros = vec![0u8; 64 << 20];
    for _ in 0..17 {
        zip.write_all(&zeros).unwrap();
    }
    zip.finish().unwrap();
    assert!(fs::metadata(&path).unwrap().len() < 8 << 20);
    let e = error_of(read_npz(&path), "bomb.npz");
    assert!(e.contains("longer than the limit of 1 GiB"), "{e}");
}

#[test]
fn json_lines_logs_refuse_a_giant_line_and_paths_out_of_the_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let root = mkdir(&dir.path().join("data"));
    our_dataset(&root);
    let manifest = root.join("manifest.jsonl");
    let good = fs::read_to_string(&manifest).unwrap();
    // A 17 MiB line (an unfinished one too): one error, not 17 MiB of memory per reader.
    let long = "x".repeat(17 << 20);
    for text in [format!("{long}\n"), long.clone()] {
        fs::write(&manifest, &text).unwrap();
        let e = error_of(read_manifest(&manifest), "manifest.jsonl");
        assert!(
            e.contains("line 1 is longer than the limit of 16 MiB"),
            "{e}"
        );
    }
    let failures = root.join("failures.jsonl");
    fs::write(&failures, format!("{long}\n")).unwrap();
    let e = error_of(read_sidecar::<FailureRecord>(&failures), "failures.jsonl");
    assert!(e.contains("longer than the limit"), "{e}");

    // Paths the readers would open outside the dataset.
    let first = good.lines().next().unwrap();
    for (bad, why) in [
        ("/etc/passwd", "is absolute"),
        ("../../secret.png", "`..` component"),
        ("tree/./x.png", "empty or `.` component"),
    ] {
        let line = first.replace("tree/0000000_left.png", bad);
        assert_ne!(line, first);
        fs::write(&manifest, format!("{line}\n")).unwrap();
        let e = error_of(read_manifest(&manifest), "manifest.jsonl");
        assert!(e.contains("`files.left`") && e.contains(why), "{e}");
        let e = error_of(open_dataset(&root, None).map(|_| ()), "manifest.jsonl");
        assert!(e.contains(why), "{e}");
    }
}

#[test]
fn pipes_and_folders_where_files_belong_are_refused_without_blocking() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("pipe.png");
    let status = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(status.success());
    for e in [
        error_of(read_rgb(&fifo), "pipe.png"),
        error_of(read_disparity_exr(&fifo).map(|_| ()), "pipe.png"),
        error_of(read_pfm(&fifo).map(|_| ()), "pipe.png"),
    ] {
        assert!(e.contains("not a regular file"), "{e}");
    }
    let e = error_of(read_rgb(dir.path()), "");
    assert!(e.contains("not a regular file"), "{e}");
}
