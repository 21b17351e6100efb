//! Image input and disparity output: BGR float images, float32 EXR / PFM, colourised PNG.

use std::path::Path;

use anyhow::{Context, Result, bail};

/// A planar float image (3, H, W) in BGR order, values 0..255 — the network's input format.
#[derive(Debug, Clone, PartialEq)]
pub struct BgrImage {
    pub width: usize,
    pub height: usize,
    /// `3 · height · width` values: the whole B plane, then G, then R.
    pub data: Vec<f32>,
}

impl BgrImage {
    pub fn zeros(width: usize, height: usize) -> Self {
        Self { width, height, data: vec![0.0; 3 * width * height] }
    }

    /// Interleaved 8-bit RGB (as `stereo-io` decodes images) to planar BGR.
    pub fn from_rgb(img: &stereo_io::RgbImage) -> Self {
        let n = img.width * img.height;
        assert_eq!(img.data.len(), 3 * n, "RGB buffer does not match {}x{}", img.width, img.height);
        let mut out = Self::zeros(img.width, img.height);
        for (i, rgb) in img.data.chunks_exact(3).enumerate() {
            out.data[i] = f32::from(rgb[2]);
            out.data[n + i] = f32::from(rgb[1]);
            out.data[2 * n + i] = f32::from(rgb[0]);
        }
        out
    }

    /// Channel `c` (0 = B, 1 = G, 2 = R).
    pub fn plane(&self, c: usize) -> &[f32] {
        let n = self.width * self.height;
        &self.data[c * n..(c + 1) * n]
    }

    pub fn plane_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.width * self.height;
        &mut self.data[c * n..(c + 1) * n]
    }
}

/// Reads a PNG / JPEG (any 8- or 16-bit colour or grey file) and returns it as BGR 0..255,
/// the channel order the reference (OpenCV) feeds the network.
pub fn read_bgr(path: impl AsRef<Path>) -> Result<BgrImage> {
    let path = path.as_ref();
    let img = image::open(path).with_context(|| format!("cannot read image {}", path.display()))?;
    let rgb = img.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    if w == 0 || h == 0 {
        bail!("image {} is empty", path.display());
    }
    let mut data = vec![0f32; 3 * w * h];
    for (i, px) in rgb.pixels().enumerate() {
        // to_rgb32f maps 8-bit values v to v/255 exactly enough; round back to the 8-bit grid
        // for 8-bit inputs so values equal OpenCV's.
        for c in 0..3 {
            let v = px.0[c] * 255.0;
            data[(2 - c) * w * h + i] = v;
        }
    }
    if matches!(
        img.color(),
        image::ColorType::Rgb8
            | image::ColorType::Rgba8
            | image::ColorType::L8
            | image::ColorType::La8
    ) {
        for v in data.iter_mut() {
            *v = v.round();
        }
    }
    Ok(BgrImage {
        width: w,
        height: h,
        data,
    })
}

/// A network prediction as a disparity map: every pixel carries a value, so every pixel is valid.
fn prediction_map(width: usize, height: usize, disp: &[f32]) -> stereo_io::DisparityMap {
    assert_eq!(disp.len(), width * height);
    stereo_io::DisparityMap { width, height, data: disp.to_vec(), valid: vec![true; disp.len()] }
}

/// Writes a float32 disparity EXR through `stereo-io` (channel `Y`, `valid` all 1).
pub fn write_exr(path: impl AsRef<Path>, width: usize, height: usize, disp: &[f32]) -> Result<()> {
    let path = path.as_ref();
    stereo_io::write_atomically(path, |tmp| stereo_io::write_disparity_exr(tmp, &prediction_map(width, height, disp), &stereo_io::DisparityMeta::default()))?;
    Ok(())
}

/// Reads a disparity EXR (ours, or any single-channel float EXR). Returns (w, h, data).
pub fn read_exr(path: impl AsRef<Path>) -> Result<(usize, usize, Vec<f32>)> {
    let (map, _) = stereo_io::read_disparity_exr(path.as_ref())?;
    Ok((map.width, map.height, map.data))
}

/// Writes a little-endian greyscale PFM (rows bottom-to-top) through `stereo-io`.
pub fn write_pfm(path: impl AsRef<Path>, width: usize, height: usize, disp: &[f32]) -> Result<()> {
    let path = path.as_ref();
    stereo_io::write_atomically(path, |tmp| stereo_io::write_disparity_pfm(tmp, &prediction_map(width, height, disp)))?;
    Ok(())
}

/// A perceptual blue→cyan→green→yellow→red ramp, `t` in 0..1.
fn colormap(t: f32) -> [u8; 3] {
    const STOPS: [(f32, [f32; 3]); 6] = [
        (0.0, [0.19, 0.07, 0.23]),
        (0.2, [0.16, 0.47, 0.93]),
        (0.4, [0.10, 0.84, 0.65]),
        (0.6, [0.64, 0.99, 0.24]),
        (0.8, [0.98, 0.62, 0.13]),
        (1.0, [0.48, 0.02, 0.01]),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut k = 0;
    while k + 2 < STOPS.len() && t > STOPS[k + 1].0 {
        k += 1;
    }
    let (t0, c0) = STOPS[k];
    let (t1, c1) = STOPS[k + 1];
    let a = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
    let mut rgb = [0u8; 3];
    for c in 0..3 {
        rgb[c] = ((c0[c] + a * (c1[c] - c0[c])) * 255.0).round() as u8;
    }
    rgb
}

/// 3×5 bitmap digits for the colour-bar labels.
const DIGITS: [[u8; 5]; 12] = [
    [0b111, 0b101, 0b101, 0b101, 0b111],
    [0b010, 0b110, 0b010, 0b010, 0b111],
    [0b111, 0b001, 0b111, 0b100, 0b111],
    [0b111, 0b001, 0b111, 0b001, 0b111],
    [0b101, 0b101, 0b111, 0b001, 0b001],
    [0b111, 0b100, 0b111, 0b001, 0b111],
    [0b111, 0b100, 0b111, 0b101, 0b111],
    [0b111, 0b001, 0b010, 0b010, 0b010],
    [0b111, 0b101, 0b111, 0b101, 0b111],
    [0b111, 0b101, 0b111, 0b001, 0b111],
    [0b000, 0b000, 0b000, 0b000, 0b010], // '.'
    [0b000, 0b000, 0b111, 0b000, 0b000], // '-'
];

fn draw_text(img: &mut image::RgbImage, x0: u32, y0: u32, text: &str, scale: u32) {
    let mut x = x0;
    for ch in text.chars() {
        let glyph = match ch {
            '0'..='9' => Some(DIGITS[ch as usize - '0' as usize]),
            '.' => Some(DIGITS[10]),
            '-' => Some(DIGITS[11]),
            _ => None,
        };
        if let Some(g) = glyph {
            for (r, bits) in g.iter().enumerate() {
                for c in 0..3u32 {
                    if bits & (0b100 >> c) != 0 {
                        for dy in 0..scale {
                            for dx in 0..scale {
                                let (px, py) = (x + c * scale + dx, y0 + r as u32 * scale + dy);
                                if px < img.width() && py < img.height() {
                                    img.put_pixel(px, py, image::Rgb([255, 255, 255]));
                                }
                            }
                        }
                    }
                }
            }
        }
        x += 4 * scale;
    }
}

/// Writes a colourised disparity PNG with a vertical colour bar (min at the bottom, max at the
/// top, labelled) on the right.
pub fn write_visualisation(
    path: impl AsRef<Path>,
    width: usize,
    height: usize,
    disp: &[f32],
) -> Result<()> {
    let path = path.as_ref();
    let finite: Vec<f32> = disp.iter().copied().filter(|v| v.is_finite()).collect();
    let lo = finite
        .iter()
        .copied()
        .fold(f32::INFINITY, f32::min)
        .min(0.0);
    let hi = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let (lo, hi) = if finite.is_empty() {
        (0.0, 1.0)
    } else {
        (lo, if hi > lo { hi } else { lo + 1.0 })
    };
    let bar_w = 16usize;
    let label_w = 48usize;
    let total_w = width + 8 + bar_w + label_w;
    let total_h = height.max(64);
    let mut img = image::RgbImage::new(total_w as u32, total_h as u32);
    for y in 0..height {
        for x in 0..width {
            let t = (disp[y * width + x] - lo) / (hi - lo);
            img.put_pixel(x as u32, y as u32, image::Rgb(colormap(t)));
        }
    }
    for y in 0..total_h {
        let t = 1.0 - y as f32 / (total_h - 1).max(1) as f32;
        for x in 0..bar_w {
            img.put_pixel((width + 8 + x) as u32, y as u32, image::Rgb(colormap(t)));
        }
    }
    let scale = if total_h >= 200 { 2 } else { 1 };
    let lx = (width + 8 + bar_w + 3) as u32;
    draw_text(&mut img, lx, 1, &format!("{hi:.1}"), scale);
    draw_text(
        &mut img,
        lx,
        (total_h as u32).saturating_sub(6 * scale + 1),
        &format!("{lo:.1}"),
        scale,
    );
    img.save(path)
        .with_context(|| format!("writing PNG {}", path.display()))
}
