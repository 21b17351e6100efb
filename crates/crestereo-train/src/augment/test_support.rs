//! Test scenes and checks shared by the augmentation units' tests.

use stereo_io::{DisparityMap, RgbImage, SampleMeta, StereoSample};

use super::{BgrImage, TrainSample, into_train_sample};

pub(super) const W: usize = 48;
pub(super) const H: usize = 32;

/// Deterministic texture: a hash of the coordinates, 0..255, different at every pixel.
pub(super) fn noise(x: i64, y: i64, salt: u64) -> f32 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    (h % 256) as f32
}

pub(super) fn planar_from_fn(
    width: usize,
    height: usize,
    f: impl Fn(usize, usize, usize) -> f32,
) -> BgrImage {
    let mut img = BgrImage::zeros(width, height);
    for c in 0..3 {
        for y in 0..height {
            for x in 0..width {
                img.data[c * width * height + y * width + x] = f(c, x, y);
            }
        }
    }
    img
}

/// A W×H image of [`noise`], each channel salted with its index.
pub(super) fn noise_image() -> BgrImage {
    planar_from_fn(W, H, |c, x, y| noise(x as i64, y as i64, c as u64))
}

pub(super) fn at(img: &BgrImage, c: usize, x: usize, y: usize) -> f32 {
    img.data[c * img.width * img.height + y * img.width + x]
}

pub(super) fn rgb_from_fn(
    width: usize,
    height: usize,
    f: impl Fn(usize, usize, usize) -> u8,
) -> RgbImage {
    let mut data = Vec::with_capacity(3 * width * height);
    for y in 0..height {
        for x in 0..width {
            data.extend((0..3).map(|c| f(c, x, y)));
        }
    }
    RgbImage {
        width,
        height,
        data,
    }
}

pub(super) fn constant_disparity(width: usize, height: usize, d: f32) -> DisparityMap {
    DisparityMap {
        width,
        height,
        data: vec![d; width * height],
        valid: vec![true; width * height],
    }
}

/// Disparities and extent of [`two_plane_scene`].
pub(super) const BACK: i64 = 3;
pub(super) const FRONT: i64 = 7;
pub(super) const FG_X0: i64 = 20;
pub(super) const FG_X1: i64 = 30;

/// A consistent stereo pair of a textured background plane (disparity `BACK`) with a
/// textured foreground slab (disparity `FRONT`) over left-view columns `FG_X0..FG_X1`,
/// rendered for both views; pixels occluded in the other view are marked invalid so every
/// valid pixel has a visible match.
pub(super) fn two_plane_scene(width: usize, height: usize) -> StereoSample {
    let on_front = |u: i64| (FG_X0..FG_X1).contains(&u);
    let texture = |u: i64, y: i64, c: usize, front: bool| {
        (noise(u, y, c as u64 + if front { 10 } else { 0 }) * 0.8 + 20.0) as u8
    };
    // The surface a view pixel sees, as (left-view column u, disparity, front?).
    let left_sees = |x: i64| {
        if on_front(x) {
            (x, FRONT, true)
        } else {
            (x, BACK, false)
        }
    };
    let right_sees = |x: i64| {
        if on_front(x + FRONT) {
            (x + FRONT, FRONT, true)
        } else {
            (x + BACK, BACK, false)
        }
    };
    let left = rgb_from_fn(width, height, |c, x, y| {
        let (u, _, front) = left_sees(x as i64);
        texture(u, y as i64, c, front)
    });
    let right = rgb_from_fn(width, height, |c, x, y| {
        let (u, _, front) = right_sees(x as i64);
        texture(u, y as i64, c, front)
    });
    let mut disp_left = DisparityMap::new(width, height);
    let mut disp_right = DisparityMap::new(width, height);
    for y in 0..height {
        for x in 0..width as i64 {
            let i = y * width + x as usize;
            let (_, d, front) = left_sees(x);
            disp_left.data[i] = d as f32;
            disp_left.valid[i] = right_sees(x - d).2 == front;
            let (_, d, front) = right_sees(x);
            disp_right.data[i] = d as f32;
            disp_right.valid[i] = left_sees(x + d).2 == front;
        }
    }
    StereoSample {
        left,
        right,
        disp_left,
        disp_right: Some(disp_right),
        valid_left: None,
        meta: SampleMeta::default(),
    }
}

/// Checks `left(x) == right(x − d(x))` at every valid pixel with an integer disparity whose
/// match is inside the image, returning how many pixels were checked.
pub(super) fn assert_consistent(s: &TrainSample, tolerance: f32) -> usize {
    let (w, h) = (s.width, s.height);
    let mut checked = 0;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let d = s.disp[i];
            if s.valid[i] == 0.0 || d.fract() != 0.0 || (d as usize) > x {
                continue;
            }
            let j = y * w + x - d as usize;
            for c in 0..3 {
                let (l, r) = (s.left[c * w * h + i], s.right[c * w * h + j]);
                assert!(
                    (l - r).abs() <= tolerance,
                    "left({x},{y})[{c}]={l} but right({},{y})={r}, d={d}",
                    x - d as usize
                );
            }
            checked += 1;
        }
    }
    checked
}

pub(super) fn train_sample_of(left: BgrImage, right: BgrImage, disp: DisparityMap) -> TrainSample {
    into_train_sample(left, right, &disp.data, &disp.valid)
}
