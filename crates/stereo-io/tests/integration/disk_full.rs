//! Writers on a filesystem that fills up (a small tmpfs of the test's own, see
//! `support/small_fs.rs`): a write either leaves a whole, readable file under its final name or
//! fails naming the file and the OS error once, leaving nothing (no short file, no temp file).
//! Exports re-run into the same folder leave no temp links, and a failed export leaves only whole
//! samples and says so.

use crate::small_fs;
use test_support::small_fs_or_skip;

use std::path::Path;

use stereo_io::datasets::export::EXPORT_INDEX_FILE;
use stereo_io::*;

use crate::io_fixtures::left_view_meta;

/// An image that does not compress (so its PNG is about as large as its pixels).
fn noise(width: usize, height: usize, seed: u64) -> RgbImage {
    let mut x = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let data = (0..width * height * 3)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect();
    RgbImage {
        width,
        height,
        data,
    }
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = walkdir::WalkDir::new(dir)
        .min_depth(1)
        .into_iter()
        .map(|e| e.unwrap())
        // Files only: a CREStereo export also makes its four (possibly empty) category folders.
        .filter(|e| !e.file_type().is_dir())
        .map(|e| {
            e.path()
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .into_owned()
        })
        .collect();
    v.sort();
    v
}

/// Tries `write` with the disk filled to several levels below what the file needs; each attempt
/// must fail cleanly or produce a file `read` accepts.
fn sweep_fill_levels(
    fs: &small_fs::SmallFs,
    file: &str,
    need: u64,
    write: &dyn Fn(&Path) -> Result<()>,
    read: &dyn Fn(&Path) -> bool,
) {
    let target = fs.path().join(file);
    for leave in [0, 4096, need / 2, need.saturating_sub(4096), need + 8192] {
        let filler = fs.fill_leaving(leave);
        let outcome = write(&target);
        match &outcome {
            Ok(()) => assert!(
                read(&target),
                "{file} with {leave} bytes free: written, but unreadable"
            ),
            Err(e) => {
                let text = e.to_string();
                assert!(
                    text.contains(&*target.to_string_lossy()),
                    "the error names the file: {text}"
                );
                assert_eq!(
                    text.matches("os error 28").count(),
                    1,
                    "the OS error once: {text}"
                );
                assert!(
                    !target.exists(),
                    "{file} with {leave} bytes free: a failed write left a file under its final name"
                );
            }
        }
        assert!(
            leave < need || outcome.is_ok(),
            "{file}: {leave} free bytes are enough for {need}, yet: {outcome:?}"
        );
        std::fs::remove_file(&filler).unwrap();
        let _ = std::fs::remove_file(&target);
        assert_eq!(
            names(fs.path()),
            Vec::<String>::new(),
            "{file} with {leave} bytes free: something was left behind"
        );
    }
}

#[test]
fn a_filling_disk_never_leaves_a_short_image_or_exr() {
    let fs = small_fs_or_skip!(1 << 20);
    let img = noise(160, 120, 1);
    let png_need = 160 * 120 * 3 + 4096;
    sweep_fill_levels(
        &fs,
        "left.png",
        png_need,
        &|p| write_png_rgb(p, &img),
        &|p| read_rgb(p).is_ok_and(|r| r == img),
    );
    let gray16 = Image {
        width: 160,
        height: 120,
        channels: 1,
        samples: Samples::U16(
            noise(160, 120, 2)
                .data
                .chunks(3)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect(),
        ),
    };
    sweep_fill_levels(
        &fs,
        "disp.png",
        160 * 120 * 2 + 4096,
        &|p| write_png(p, &gray16),
        &|p| read_image(p).is_ok(),
    );
    sweep_fill_levels(
        &fs,
        "left.jpg",
        64 * 1024,
        &|p| write_jpeg_rgb(p, &img, 95),
        &|p| read_rgb(p).is_ok(),
    );
    let mut map = DisparityMap::new(160, 120);
    for (i, d) in map.data.iter_mut().enumerate() {
        *d = (i as f32 * 0.618_034).fract() * 100.0;
        map.valid[i] = true;
    }
    let meta = left_view_meta(100.0, 0.1);
    sweep_fill_levels(
        &fs,
        "disp.exr",
        160 * 120 * 4 + 8192,
        &|p| write_disparity_exr(p, &map, &meta),
        &|p| read_disparity_exr(p).is_ok_and(|(m, _)| m.data == map.data),
    );
    sweep_fill_levels(
        &fs,
        "disp.pfm",
        160 * 120 * 4 + 4096,
        &|p| write_disparity_pfm(p, &map),
        &|p| read_disparity_pfm(p).is_ok(),
    );
}

#[test]
fn a_failed_rewrite_keeps_the_old_file_whole() {
    let fs = small_fs_or_skip!(1 << 20);
    let target = fs.path().join("left.png");
    let old = noise(32, 32, 3);
    write_png_rgb(&target, &old).unwrap();
    let filler = fs.fill_leaving(0);
    assert!(write_png_rgb(&target, &noise(160, 120, 4)).is_err());
    assert_eq!(read_rgb(&target).unwrap(), old);
    std::fs::remove_file(filler).unwrap();
    assert_eq!(names(fs.path()), vec!["left.png"]);
}

/// Export to the CREStereo layout with lossless images, the source's layout detected.
fn lossless_crestereo_export() -> ExportOptions {
    ExportOptions {
        from: None,
        to: WritableFormat::Crestereo,
        images: ImageEncoding::Lossless,
        read: Default::default(),
    }
}

/// A CREStereo-layout dataset of `n` samples with incompressible images.
fn source_dataset(root: &Path, n: usize) {
    let mut w = create_writer(WritableFormat::Crestereo, root, ImageEncoding::Lossless).unwrap();
    for i in 0..n {
        let mut d = DisparityMap::new(96, 72);
        for (k, v) in d.data.iter_mut().enumerate() {
            *v = ((k * 7 + i) % 200) as f32 / 4.0;
        }
        d.valid.fill(true);
        let sample = StereoSample {
            left: noise(96, 72, 10 + i as u64),
            right: noise(96, 72, 50 + i as u64),
            disp_left: d.clone(),
            disp_right: Some(d),
            valid_left: None,
            meta: SampleMeta::default(),
        };
        w.write(i, &format!("s{i:03}"), &sample).unwrap();
    }
}

#[test]
fn re_exporting_into_the_same_folder_is_idempotent_and_leaves_no_temp_links() {
    let t = tempfile::tempdir().unwrap();
    let src = t.path().join("src");
    source_dataset(&src, 4);
    let out = t.path().join("out");
    let opts = lossless_crestereo_export();
    let first = export_dataset(&src, &out, &opts).unwrap();
    let listing = names(&out);
    let bytes: Vec<Vec<u8>> = listing
        .iter()
        .map(|n| std::fs::read(out.join(n)).unwrap())
        .collect();
    for _ in 0..3 {
        let again = export_dataset(&src, &out, &opts).unwrap();
        assert_eq!(again.samples, first.samples);
        assert_eq!(
            names(&out),
            listing,
            "a re-export adds or leaves nothing (no .NAME.partial-PID links)"
        );
        assert_eq!(
            listing
                .iter()
                .map(|n| std::fs::read(out.join(n)).unwrap())
                .collect::<Vec<_>>(),
            bytes
        );
    }
}

#[test]
fn an_export_onto_a_full_disk_leaves_whole_samples_and_says_so() {
    let fs = small_fs_or_skip!(1 << 20);
    let t = tempfile::tempdir().unwrap();
    let src = t.path().join("src");
    source_dataset(&src, 12);
    // The source is on another filesystem: every file is copied, and the disk fills mid-way.
    let out = fs.path().join("out");
    let opts = lossless_crestereo_export();
    let filler = fs.fill_leaving(200 * 1024);
    let e = export_dataset(&src, &out, &opts).unwrap_err().to_string();
    assert!(
        e.contains("export stopped at sample") && e.contains("os error 28") && e.contains("re-run"),
        "{e}"
    );
    assert_eq!(e.matches("os error 28").count(), 1, "{e}");
    let left = names(&out);
    assert!(
        left.iter().all(|n| !is_temp_name(n)),
        "no temp files: {left:?}"
    );
    let ds = open_dataset(&out, Some(DatasetFormat::Crestereo)).unwrap();
    assert!(
        !ds.is_empty() && ds.len() < 12,
        "the disk filled mid-way: {} samples",
        ds.len()
    );
    for n in 0..ds.len() {
        ds.sample(n)
            .unwrap_or_else(|e| panic!("sample {n} left by a failed export is not whole: {e}"));
    }
    let files_per_sample = 4;
    let listed = std::fs::read_to_string(out.join(EXPORT_INDEX_FILE)).unwrap_or_default();
    assert_eq!(
        left.len(),
        ds.len() * files_per_sample + usize::from(!listed.is_empty()),
        "only whole samples: {left:?}"
    );
    assert_eq!(
        listed.lines().count(),
        ds.len(),
        "the index lists what was left"
    );
    assert!(
        e.contains(&format!("the {} sample(s) before it", ds.len())),
        "{e}"
    );
    // With room again the same command finishes the job.
    std::fs::remove_file(filler).unwrap();
    assert_eq!(export_dataset(&src, &out, &opts).unwrap().samples, 12);
    assert_eq!(open_dataset(&out, None).unwrap().len(), 12);
    assert!(names(&out).iter().all(|n| !is_temp_name(n)));
}
