//! Compares JPEG decoders with a reference decode: for every `NAME.jpg` in a folder that has a
//! `NAME.ref.png` beside it (the reference pixels, e.g. `cv2.imread` saved losslessly), prints
//! the largest and mean absolute difference of the `image` crate's decoder and of stereo-io's.
//!
//! `cargo run --release -p stereo-io --example jpeg_vs_reference -- DIR`

use std::path::Path;

fn diff(a: &[u8], b: &[u8]) -> (u8, f64, f64) {
    assert_eq!(a.len(), b.len(), "sizes differ");
    let mut max = 0u8;
    let mut sum = 0u64;
    let mut differing = 0usize;
    for (x, y) in a.iter().zip(b) {
        let d = x.abs_diff(*y);
        max = max.max(d);
        sum += u64::from(d);
        differing += usize::from(d != 0);
    }
    (
        max,
        sum as f64 / a.len() as f64,
        100.0 * differing as f64 / a.len() as f64,
    )
}

fn main() {
    let dir = std::env::args()
        .nth(1)
        .expect("usage: jpeg_vs_reference DIR");
    let mut names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "jpg"))
        .collect();
    names.sort();
    println!(
        "{:<28} {:>26} {:>26}",
        "file", "image crate: max/mean/%≠", "stereo-io: max/mean/%≠"
    );
    let (mut worst_before, mut worst_after) = (0u8, 0u8);
    for jpg in names {
        let reference = jpg.with_extension("ref.png");
        if !reference.is_file() {
            continue;
        }
        let want = stereo_io::read_rgb(&reference).unwrap();
        let bytes = std::fs::read(&jpg).unwrap();
        let before = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg)
            .unwrap()
            .to_rgb8()
            .into_raw();
        let after = stereo_io::read_rgb(Path::new(&jpg)).unwrap();
        let b = diff(&before, &want.data);
        let a = diff(&after.data, &want.data);
        worst_before = worst_before.max(b.0);
        worst_after = worst_after.max(a.0);
        let name = jpg.file_name().unwrap().to_string_lossy();
        println!(
            "{name:<28} {:>10} {:>7.4} {:>6.2}% {:>10} {:>7.4} {:>6.2}%",
            b.0, b.1, b.2, a.0, a.1, a.2
        );
    }
    println!("largest difference: image crate {worst_before}, stereo-io {worst_after}");
}
