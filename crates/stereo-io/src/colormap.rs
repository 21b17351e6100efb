//! Disparity to colour, for people looking at maps: one ramp and one range rule, shared by
//! `crestereo infer --viz` and the generator's contact sheet.
//!
//! - Ramp: hue from blue (small disparity, far) through cyan, green and yellow to red (large,
//!   near); invalid pixels are black.
//! - Range: [`DisparityRange::of`] spans the valid finite values and always includes 0, so a map
//!   of positive disparities starts at blue for zero and ends at red for its largest value.
//!
//! The other maps ([`crate::maps`]), for the contact sheet and the report, black where there is
//! no surface:
//! - depth: inverse depth (proportional to disparity) on the same ramp, over a range the caller
//!   picks ([`inverse_depth_range`]): near red, far blue;
//! - normals: each component `n` as `(n + 1) / 2` of full scale in R, G, B;
//! - instance and semantic ids: a fixed categorical palette ([`categorical`]).

use crate::disparity::DisparityMap;
use crate::image_io::RgbImage;
use crate::maps::{DepthMap, IdMap, NormalMap};

/// The disparities mapped to the two ends of the ramp; values outside are clamped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisparityRange {
    pub lo: f32,
    pub hi: f32,
}

impl DisparityRange {
    /// `lo..hi`; an empty or inverted range becomes `lo..lo + 1` (everything maps to `lo`'s colour).
    pub fn new(lo: f32, hi: f32) -> Self {
        Self {
            lo,
            hi: if hi > lo { hi } else { lo + 1.0 },
        }
    }

    /// The range rule: from `min(0, smallest)` to the largest valid finite value; `0..1` when
    /// the map has none.
    pub fn of(map: &DisparityMap) -> Self {
        let mut values = map
            .data
            .iter()
            .zip(&map.valid)
            .filter(|&(d, &v)| v && d.is_finite())
            .map(|(&d, _)| d)
            .peekable();
        if values.peek().is_none() {
            return Self::new(0.0, 1.0);
        }
        let (lo, hi) = values.fold((0f32, f32::NEG_INFINITY), |(lo, hi), d| {
            (lo.min(d), hi.max(d))
        });
        Self::new(lo, hi)
    }

    /// Where `d` falls on the ramp, 0..=1 (non-finite values at 0).
    pub fn position(&self, d: f32) -> f32 {
        let t = (d - self.lo) / (self.hi - self.lo);
        if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// The ramp at `t` in 0..=1: hue from 240° (blue) down to 0° (red), full saturation and value.
pub fn ramp(t: f32) -> [u8; 3] {
    let t = if t.is_finite() {
        f64::from(t.clamp(0.0, 1.0))
    } else {
        0.0
    };
    hue_rgb((1.0 - t) * 4.0).map(|c| (c * 255.0).round() as u8)
}

/// The fully saturated colour of hue `h` in sixths of the circle (0 red, 2 green, 4 blue), each
/// channel 0..=1.
fn hue_rgb(h: f64) -> [f64; 3] {
    let x = 1.0 - (h % 2.0 - 1.0).abs();
    match h as u32 {
        0 => [1.0, x, 0.0],
        1 => [x, 1.0, 0.0],
        2 => [0.0, 1.0, x],
        3 => [0.0, x, 1.0],
        4 => [x, 0.0, 1.0],
        _ => [1.0, 0.0, x],
    }
}

/// An image of `width` × `height` from its pixels' colours, row by row.
fn rgb_image(width: usize, height: usize, pixels: impl Iterator<Item = [u8; 3]>) -> RgbImage {
    RgbImage {
        width,
        height,
        data: pixels.flatten().collect(),
    }
}

/// Colours every pixel of `map` by its place in `range`; invalid pixels are black.
pub fn colourise(map: &DisparityMap, range: DisparityRange) -> RgbImage {
    let pixels = map.data.iter().zip(&map.valid);
    rgb_image(
        map.width,
        map.height,
        pixels.map(|(&d, &v)| {
            if v {
                ramp(range.position(d))
            } else {
                [0, 0, 0]
            }
        }),
    )
}

/// Whether a depth value is a surface (positive and finite; 0 is "no surface").
fn is_surface(z: f32) -> bool {
    z.is_finite() && z > 0.0
}

/// The range of inverse depth (1/m) over the surfaces of `maps`, for [`colourise_depth`]: from
/// the farthest surface's to the nearest's; `0..1` when there is none.
pub fn inverse_depth_range<'a>(maps: impl IntoIterator<Item = &'a DepthMap>) -> DisparityRange {
    let (lo, hi) = maps
        .into_iter()
        .flat_map(|m| m.data.iter().copied().filter(|&z| is_surface(z)))
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), z| {
            (lo.min(1.0 / z), hi.max(1.0 / z))
        });
    if lo.is_finite() && hi.is_finite() {
        DisparityRange::new(lo, hi)
    } else {
        DisparityRange::new(0.0, 1.0)
    }
}

/// Colours each surface pixel of `map` by its inverse depth's place in `range` (1/m) on the
/// ramp (near red, far blue); no surface is black.
pub fn colourise_depth(map: &DepthMap, range: DisparityRange) -> RgbImage {
    let pixels = map.data.iter().map(|&z| {
        if is_surface(z) {
            ramp(range.position(1.0 / z))
        } else {
            [0, 0, 0]
        }
    });
    rgb_image(map.width, map.height, pixels)
}

/// Colours each normal as `(n + 1) / 2` of full scale per component (x red, y green, z blue);
/// no surface (`[0, 0, 0]`, or a non-finite normal) is black.
pub fn colourise_normals(map: &NormalMap) -> RgbImage {
    let pixels = map.data.iter().map(|n| {
        if n.iter().all(|c| c.is_finite()) && n.iter().any(|&c| c != 0.0) {
            n.map(|c| ((c.clamp(-1.0, 1.0) + 1.0) * 0.5 * 255.0).round() as u8)
        } else {
            [0, 0, 0]
        }
    });
    rgb_image(map.width, map.height, pixels)
}

/// The first ids' colours: well apart from each other and from black.
const CATEGORICAL: [[u8; 3]; 12] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [188, 189, 34],
    [23, 190, 207],
    [255, 187, 120],
    [152, 223, 138],
    [174, 199, 232],
];

/// The colour of id `id` in every picture of instance or semantic ids: black for 0 (no surface),
/// a fixed table for ids 1 to 12, then hues a golden-ratio turn apart at alternating brightness
/// (deterministic, never black, never the same colour for neighbouring ids).
pub fn categorical(id: u16) -> [u8; 3] {
    match id {
        0 => [0, 0, 0],
        i if usize::from(i) <= CATEGORICAL.len() => CATEGORICAL[usize::from(i) - 1],
        i => {
            let hue = (f64::from(i) * 0.618_033_988_749_895).fract() * 6.0;
            let (s, v) = [(0.65, 0.95), (0.9, 0.75), (0.45, 0.85)][usize::from(i) % 3];
            hue_rgb(hue).map(|c| ((1.0 - s + s * c) * v * 255.0).round() as u8)
        }
    }
}

/// Colours each id by [`categorical`] (0, no surface, black).
pub fn colourise_ids(map: &IdMap) -> RgbImage {
    rgb_image(
        map.width,
        map.height,
        map.data.iter().map(|&id| categorical(id)),
    )
}

/// `#rrggbb` of a colour (for HTML).
pub fn hex(colour: [u8; 3]) -> String {
    format!("#{:02x}{:02x}{:02x}", colour[0], colour[1], colour[2])
}

/// Space between the map and the bar, the bar's width and the label column's width, in pixels.
const BAR_GAP: usize = 8;
const BAR_WIDTH: usize = 16;
const LABEL_WIDTH: usize = 48;
/// The bar is at least this tall, so its labels fit beside small maps.
const MIN_BAR_HEIGHT: usize = 64;

/// [`colourise`] with a vertical colour bar on the right (`range.hi` at the top, `range.lo` at
/// the bottom), both ends labelled with one decimal, on a black background.
pub fn colourise_with_bar(map: &DisparityMap, range: DisparityRange) -> RgbImage {
    let width = map.width + BAR_GAP + BAR_WIDTH + LABEL_WIDTH;
    let height = map.height.max(MIN_BAR_HEIGHT);
    let mut out = RgbImage {
        width,
        height,
        data: vec![0; width * height * 3],
    };
    let body = colourise(map, range);
    for y in 0..map.height {
        let (s, d) = (y * map.width * 3, y * width * 3);
        out.data[d..d + map.width * 3].copy_from_slice(&body.data[s..s + map.width * 3]);
    }
    for y in 0..height {
        let colour = ramp(1.0 - y as f32 / (height - 1) as f32);
        for x in map.width + BAR_GAP..map.width + BAR_GAP + BAR_WIDTH {
            put(&mut out, x, y, colour);
        }
    }
    let scale = if height >= 200 { 2 } else { 1 };
    let x = map.width + BAR_GAP + BAR_WIDTH + 3;
    draw_label(&mut out, x, 1, &format!("{:.1}", range.hi), scale);
    draw_label(
        &mut out,
        x,
        height.saturating_sub(GLYPH_ROWS * scale + scale + 1),
        &format!("{:.1}", range.lo),
        scale,
    );
    out
}

fn put(img: &mut RgbImage, x: usize, y: usize, colour: [u8; 3]) {
    if x < img.width && y < img.height {
        let i = (y * img.width + x) * 3;
        img.data[i..i + 3].copy_from_slice(&colour);
    }
}

const GLYPH_ROWS: usize = 5;

/// 3×5 bitmaps of the characters a label uses, most significant bit = left column.
fn glyph(ch: char) -> Option<[u8; GLYPH_ROWS]> {
    Some(match ch {
        '0' => [0b111, 0b101, 0b101, 0b101, 0b111],
        '1' => [0b010, 0b110, 0b010, 0b010, 0b111],
        '2' => [0b111, 0b001, 0b111, 0b100, 0b111],
        '3' => [0b111, 0b001, 0b111, 0b001, 0b111],
        '4' => [0b101, 0b101, 0b111, 0b001, 0b001],
        '5' => [0b111, 0b100, 0b111, 0b001, 0b111],
        '6' => [0b111, 0b100, 0b111, 0b101, 0b111],
        '7' => [0b111, 0b001, 0b010, 0b010, 0b010],
        '8' => [0b111, 0b101, 0b111, 0b101, 0b111],
        '9' => [0b111, 0b101, 0b111, 0b001, 0b111],
        '.' => [0b000, 0b000, 0b000, 0b000, 0b010],
        '-' => [0b000, 0b000, 0b111, 0b000, 0b000],
        _ => return None,
    })
}

/// White text, each glyph pixel a `scale`×`scale` square, glyphs 4·`scale` apart.
fn draw_label(img: &mut RgbImage, x0: usize, y0: usize, text: &str, scale: usize) {
    for (k, rows) in text
        .chars()
        .enumerate()
        .filter_map(|(k, ch)| Some((k, glyph(ch)?)))
    {
        for (r, bits) in rows.iter().enumerate() {
            for c in (0..3).filter(|c| bits & (0b100 >> c) != 0) {
                for (dx, dy) in (0..scale).flat_map(|dx| (0..scale).map(move |dy| (dx, dy))) {
                    put(
                        img,
                        x0 + (4 * k + c) * scale + dx,
                        y0 + r * scale + dy,
                        [255; 3],
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(data: Vec<f32>, valid: Vec<bool>) -> DisparityMap {
        DisparityMap {
            width: data.len(),
            height: 1,
            data,
            valid,
        }
    }

    #[test]
    fn ramp_runs_from_blue_through_green_to_red() {
        assert_eq!(ramp(0.0), [0, 0, 255]);
        assert_eq!(ramp(0.25), [0, 255, 255]);
        assert_eq!(ramp(0.5), [0, 255, 0]);
        assert_eq!(ramp(0.75), [255, 255, 0]);
        assert_eq!(ramp(1.0), [255, 0, 0]);
        assert_eq!(ramp(f32::NAN), ramp(0.0));
        assert_eq!(ramp(7.0), ramp(1.0));
    }

    #[test]
    fn range_includes_zero_and_ignores_invalid_and_non_finite_values() {
        let m = map(
            vec![2.0, 10.0, 50.0, f32::INFINITY],
            vec![true, true, false, true],
        );
        assert_eq!(DisparityRange::of(&m), DisparityRange { lo: 0.0, hi: 10.0 });
        let m = map(vec![-3.0, 4.0], vec![true, true]);
        assert_eq!(DisparityRange::of(&m), DisparityRange { lo: -3.0, hi: 4.0 });
        // flat, empty and all-invalid maps still give a usable range
        assert_eq!(
            DisparityRange::of(&map(vec![0.0, 0.0], vec![true, true])),
            DisparityRange { lo: 0.0, hi: 1.0 }
        );
        assert_eq!(
            DisparityRange::of(&map(vec![5.0], vec![false])),
            DisparityRange { lo: 0.0, hi: 1.0 }
        );
        assert_eq!(
            DisparityRange::new(-2.0, -4.0),
            DisparityRange { lo: -2.0, hi: -1.0 }
        );
    }

    #[test]
    fn colourise_maps_the_range_ends_and_blacks_out_invalid_pixels() {
        let m = map(
            vec![0.0, 5.0, 10.0, 3.0, 12.0],
            vec![true, true, true, false, true],
        );
        let img = colourise(&m, DisparityRange::new(0.0, 10.0));
        assert_eq!((img.width, img.height), (5, 1));
        assert_eq!(
            img.data,
            [
                [0, 0, 255],
                [0, 255, 0],
                [255, 0, 0],
                [0, 0, 0],
                [255, 0, 0]
            ]
            .concat()
        );
    }

    #[test]
    fn bar_spans_the_ramp_beside_the_map_and_carries_labels() {
        let m = map(vec![1.0, 2.0, 3.0], vec![true; 3]);
        let img = colourise_with_bar(&m, DisparityRange::of(&m));
        assert_eq!(
            (img.width, img.height),
            (3 + BAR_GAP + BAR_WIDTH + LABEL_WIDTH, MIN_BAR_HEIGHT)
        );
        let px = |x: usize, y: usize| -> [u8; 3] {
            img.data[(y * img.width + x) * 3..][..3].try_into().unwrap()
        };
        assert_eq!(px(2, 0), [255, 0, 0]);
        assert_eq!(px(0, 1), [0, 0, 0]); // below the one-row map
        let bar_x = 3 + BAR_GAP;
        assert_eq!(px(bar_x, 0), [255, 0, 0]);
        assert_eq!(px(bar_x, MIN_BAR_HEIGHT - 1), [0, 0, 255]);
        let labels =
            (0..img.height).flat_map(|y| (bar_x + BAR_WIDTH..img.width).map(move |x| (x, y)));
        let white = labels.filter(|&(x, y)| px(x, y) == [255; 3]).count();
        assert!(white > 20, "labels missing ({white} white pixels)");
    }

    #[test]
    fn depth_runs_near_red_to_far_blue_and_blacks_out_no_surface() {
        let m = DepthMap {
            width: 4,
            height: 1,
            data: vec![1.0, 4.0, 0.0, f32::NAN],
        };
        let range = inverse_depth_range([&m]);
        assert_eq!(range, DisparityRange { lo: 0.25, hi: 1.0 });
        let img = colourise_depth(&m, range);
        assert_eq!(
            img.data,
            [[255, 0, 0], [0, 0, 255], [0, 0, 0], [0, 0, 0]].concat()
        );
        let empty = DepthMap {
            width: 1,
            height: 1,
            data: vec![0.0],
        };
        assert_eq!(inverse_depth_range([&empty]), DisparityRange::new(0.0, 1.0));
    }

    #[test]
    fn normals_are_half_offset_rgb_and_ids_a_fixed_palette() {
        let m = NormalMap {
            width: 3,
            height: 1,
            data: vec![[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0; 3]],
        };
        assert_eq!(
            colourise_normals(&m).data,
            [[128, 128, 0], [255, 128, 128], [0, 0, 0]].concat()
        );
        assert_eq!(categorical(0), [0, 0, 0]);
        assert_eq!(categorical(1), [31, 119, 180]);
        let colours: Vec<[u8; 3]> = (1..=400).map(categorical).collect();
        assert!(colours.iter().all(|&c| c != [0, 0, 0]));
        assert!(colours.windows(2).all(|w| w[0] != w[1]));
        assert_eq!(categorical(300), categorical(300));
        let ids = IdMap {
            width: 2,
            height: 1,
            data: vec![0, 2],
        };
        assert_eq!(
            colourise_ids(&ids).data,
            [[0, 0, 0], categorical(2)].concat()
        );
        assert_eq!(hex([255, 0, 16]), "#ff0010");
    }
}
