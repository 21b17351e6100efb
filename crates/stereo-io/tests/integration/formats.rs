//! Round trips of every disparity and image format, and malformed files that must give errors
//! naming the file and the problem.

use std::path::Path;

use stereo_io::*;

use crate::io_fixtures::left_view_meta;

fn sample_map(w: usize, h: usize) -> DisparityMap {
    let mut m = DisparityMap::new(w, h);
    for (i, (d, v)) in m.data.iter_mut().zip(m.valid.iter_mut()).enumerate() {
        *v = i % 7 != 3;
        *d = if *v {
            0.37 + (i as f32 * 1.618).rem_euclid(180.0)
        } else {
            0.0
        };
    }
    m
}

fn err_of<T: std::fmt::Debug>(r: Result<T>) -> String {
    r.unwrap_err().to_string()
}

#[test]
fn pfm_round_trip_is_exact_in_both_byte_orders_and_flips_rows() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_map(5, 4);
    let p = dir.path().join("d.pfm");
    write_disparity_pfm(&p, &map).unwrap();
    assert_eq!(read_disparity_pfm(&p).unwrap(), map);
    assert_eq!(read_disparity(&p, None).unwrap().0, map);

    // 3 channels, big-endian, hand-checked byte layout: the first stored row is the bottom one.
    let img = FloatImage {
        width: 2,
        height: 3,
        channels: 3,
        data: (0..18).map(|i| i as f32 * 0.5 - 2.0).collect(),
    };
    for endian in [Endian::Big, Endian::Little] {
        let q = dir.path().join(format!("c{endian:?}.pfm"));
        write_pfm(&q, &img, endian).unwrap();
        let bytes = std::fs::read(&q).unwrap();
        let header_len = bytes.len() - 18 * 4;
        let first: [u8; 4] = bytes[header_len..header_len + 4].try_into().unwrap();
        let first = if endian == Endian::Big {
            f32::from_be_bytes(first)
        } else {
            f32::from_le_bytes(first)
        };
        assert_eq!(first, img.data[12], "bottom row first");
        assert_eq!(read_pfm(&q).unwrap(), img);
    }
    // A 3-channel file read as disparity gives its first channel (issue 15: tools write `PF`
    // disparities with the value repeated).
    let q = dir.path().join("cBig.pfm");
    let d = read_disparity_pfm(&q).unwrap();
    assert_eq!((d.width, d.height), (2, 3));
    assert_eq!(
        d.data,
        img.data.iter().step_by(3).copied().collect::<Vec<f32>>()
    );
}

#[test]
fn pfm_written_by_hand_with_odd_whitespace_and_inf_reads() {
    // Middlebury-style: big scale magnitude, inf = no ground truth.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.pfm");
    let mut bytes = b"Pf\n2 1\n-0.0039\n".to_vec();
    for v in [f32::INFINITY, 12.5] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(&p, &bytes).unwrap();
    let m = read_disparity_pfm(&p).unwrap();
    assert_eq!(
        (m.data.clone(), m.valid.clone()),
        (vec![0.0, 12.5], vec![false, true])
    );
}

#[test]
fn pfm_errors_name_file_and_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, &[u8], &str); 6] = [
        ("magic.pfm", b"P6\n1 1\n255\n\0\0\0", "magic"),
        ("trunc.pfm", b"Pf\n4 4\n-1.0\n\0\0\0\0", "truncated"),
        ("zero.pfm", b"Pf\n0 4\n-1.0\n", "width"),
        ("scale.pfm", b"Pf\n1 1\n0\n\0\0\0\0", "scale"),
        ("huge.pfm", b"Pf\n99999999 99999999\n-1\n", "width"),
        ("empty.pfm", b"", "missing"),
    ];
    for (name, bytes, problem) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let e = err_of(read_disparity_pfm(&p));
        assert!(e.contains(name) && e.contains(problem), "{name}: {e}");
    }
    let p = dir.path().join("nan.pfm");
    let mut b = b"Pf\n1 1\n-1.0\n".to_vec();
    b.extend_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&p, b).unwrap();
    let e = err_of(read_disparity_pfm(&p));
    assert!(e.contains("nan.pfm") && e.contains("NaN"), "{e}");
}

#[test]
fn png16_round_trip_within_quantisation_and_zero_is_invalid() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_map(9, 5);
    for scale in [CRESTEREO_SCALE, KITTI_SCALE] {
        let p = dir.path().join(format!("d{scale}.png"));
        write_disparity_png16(&p, &map, scale).unwrap();
        let back = read_disparity_png16(&p, scale).unwrap();
        assert_eq!(back.valid, map.valid);
        for ((a, b), v) in back.data.iter().zip(&map.data).zip(&map.valid) {
            if *v {
                assert!(
                    (a - b).abs() <= 0.5 / scale + 1e-6,
                    "scale {scale}: {a} vs {b}"
                );
                // Exactly a multiple of 1/scale.
                assert_eq!((a * scale).fract(), 0.0);
            } else {
                assert_eq!(*a, 0.0);
            }
        }
        let img = read_image(&p).unwrap();
        assert!(matches!(img.samples, Samples::U16(_)) && img.channels == 1);
    }
    // A tiny valid disparity stays valid (stored as 1/scale), a too large one is refused.
    let mut m = DisparityMap::new(2, 1);
    m.data = vec![0.001, 3000.0];
    m.valid = vec![true, false];
    let p = dir.path().join("small.png");
    write_disparity_png16(&p, &m, 32.0).unwrap();
    assert_eq!(
        read_disparity_png16(&p, 32.0).unwrap().data,
        vec![1.0 / 32.0, 0.0]
    );
    m.valid[1] = true;
    let e = err_of(write_disparity_png16(&p, &m, 256.0));
    assert!(e.contains("small.png") && e.contains("3000"), "{e}");
}

#[test]
fn png16_reader_rejects_wrong_bit_depth_and_garbage() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("rgb8.png");
    write_png_rgb(
        &p,
        &RgbImage {
            width: 1,
            height: 1,
            data: vec![1, 2, 3],
        },
    )
    .unwrap();
    let e = err_of(read_disparity_png16(&p, 256.0));
    assert!(e.contains("rgb8.png") && e.contains("16-bit grey"), "{e}");
    let g = dir.path().join("garbage.png");
    std::fs::write(&g, b"\x89PNG\r\n\x1a\n garbage").unwrap();
    assert!(err_of(read_disparity_png16(&g, 256.0)).contains("garbage.png"));
    let good = dir.path().join("good.png");
    write_disparity_png16(&good, &sample_map(16, 16), 32.0).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let cut = dir.path().join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    assert!(err_of(read_disparity_png16(&cut, 32.0)).contains("cut.png"));
}

#[test]
fn sintel_round_trip_keeps_2_pow_minus_14_resolution() {
    let dir = tempfile::tempdir().unwrap();
    let mut map = sample_map(6, 3);
    map.valid.iter_mut().for_each(|v| *v = true);
    map.data[0] = 1023.99;
    let p = dir.path().join("s.png");
    write_disparity_sintel(&p, &map).unwrap();
    let back = read_disparity_sintel(&p).unwrap();
    for (a, b) in back.data.iter().zip(&map.data) {
        assert!((a - b).abs() <= 0.5 / 16384.0 + b * 1e-7, "{a} vs {b}");
    }
    assert_eq!(
        read_disparity(&p, Some(DisparityFormat::SintelPng))
            .unwrap()
            .0,
        back
    );
    let e = err_of(read_disparity_sintel(&dir.path().join("missing.png")));
    assert!(e.contains("missing.png"), "{e}");
}

#[test]
fn npy_round_trip_and_numpy_compatible_header() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_map(7, 3);
    let p = dir.path().join("d.npy");
    write_disparity_npy(&p, &map).unwrap();
    assert_eq!(read_disparity_npy(&p).unwrap(), map);
    let bytes = std::fs::read(&p).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!((10 + header_len) % 64, 0, "data aligned as numpy writes it");
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
    assert!(
        header.contains("'descr': '<f4'") && header.contains("'shape': (3, 7)"),
        "{header}"
    );
    // A 3-D array is not a disparity map.
    let q = dir.path().join("rgb.npy");
    write_npy(
        &q,
        &NpyArray {
            shape: vec![2, 2, 3],
            data: vec![0.0; 12],
        },
    )
    .unwrap();
    let e = err_of(read_disparity_npy(&q));
    assert!(e.contains("rgb.npy") && e.contains("(H, W)"), "{e}");
}

#[test]
fn generic_entry_points_dispatch_on_the_file_name() {
    let dir = tempfile::tempdir().unwrap();
    let map = sample_map(4, 4);
    let meta = left_view_meta(700.0, 0.1);
    for name in ["a.exr", "a.pfm", "a.npy"] {
        let p = dir.path().join(name);
        write_disparity(&p, &map, &meta, None).unwrap();
        assert_eq!(read_disparity(&p, None).unwrap().0, map, "{name}");
    }
    assert_eq!(
        read_disparity(&dir.path().join("a.exr"), None).unwrap().1,
        meta
    );
    assert_eq!(
        DisparityFormat::from_path(Path::new("x_left.disp.png")),
        Some(DisparityFormat::Png16 { scale: 32.0 })
    );
    assert_eq!(
        "png16:64".parse::<DisparityFormat>().unwrap(),
        DisparityFormat::Png16 { scale: 64.0 }
    );
    assert!(
        read_disparity(Path::new("x.tif"), None)
            .unwrap_err()
            .to_string()
            .contains("x.tif")
    );
}

#[test]
fn images_keep_bit_depth_and_channels() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        Image {
            width: 3,
            height: 2,
            channels: 1,
            samples: Samples::U8((0..6).map(|i| i * 40).collect()),
        },
        Image {
            width: 3,
            height: 2,
            channels: 3,
            samples: Samples::U8((0..18).map(|i| i * 13).collect()),
        },
        Image {
            width: 3,
            height: 2,
            channels: 1,
            samples: Samples::U16((0..6).map(|i| i * 10_000 + 7).collect()),
        },
        Image {
            width: 2,
            height: 2,
            channels: 4,
            samples: Samples::U16((0..16).map(|i| i * 4000 + 1).collect()),
        },
    ];
    for (i, img) in cases.iter().enumerate() {
        let p = dir.path().join(format!("i{i}.png"));
        write_png(&p, img).unwrap();
        assert_eq!(&read_image(&p).unwrap(), img, "case {i}");
    }
    // 16-bit colour reads as RGB8 through read_rgb (high byte).
    let rgb = read_rgb(&dir.path().join("i2.png")).unwrap();
    assert_eq!(&rgb.data[..3], &[0, 0, 0]);
    assert_eq!(
        rgb.data[15],
        ((5 * 10_000 + 7) as f32 / 257.0).round() as u8
    );
    // JPEG: lossy, close; the reader recognises it by content even under a .png name.
    let img = RgbImage {
        width: 16,
        height: 8,
        data: (0..16 * 8 * 3).map(|i| (i % 200) as u8 / 4 + 60).collect(),
    };
    let j = dir.path().join("j.png");
    write_jpeg_rgb(&j, &img, 95).unwrap();
    let back = read_rgb(&j).unwrap();
    let mean_err: f64 = back
        .data
        .iter()
        .zip(&img.data)
        .map(|(&a, &b)| (a as f64 - b as f64).abs())
        .sum::<f64>()
        / img.data.len() as f64;
    assert!(mean_err < 4.0, "{mean_err}");
}
