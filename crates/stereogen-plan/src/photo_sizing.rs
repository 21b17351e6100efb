//! Photo sizing: a photo is tiled often enough that it is never magnified past the recipe's limit
//! (no blurry photo stretched over a large surface), and where it is strongly minified the worker
//! gets a downsampled copy, a power-of-two mip level (no moiré: Cycles does not mipmap).

use super::spec::BaseColor;

/// The smallest side a downsampled copy may have.
const MIN_TEXTURE_PX: f64 = 8.0;

/// Sizes `base`, if it is a photo, for an object `screen_px` pixels across its largest axis
/// whose world extents along X, Y, Z are proportional to `axes`. `photo` is the photo's width
/// and height; `texel_px` the allowed [min, max] screen pixels per photo pixel.
pub fn size_photo(
    base: &mut BaseColor,
    photo: [u32; 2],
    screen_px: f64,
    axes: [f64; 3],
    texel_px: [f64; 2],
) {
    let BaseColor::Image {
        scale,
        texture_px,
        stretch,
        ..
    } = base
    else {
        return;
    };
    let [lo, hi] = texel_px;
    let short = f64::from(photo[0].min(photo[1])).max(1.0);
    let long = f64::from(photo[0].max(photo[1])).max(1.0);
    // Texture coordinates are object coordinates times `scale`; the object spans 2 units along
    // its largest axis, so one repeat covers screen_px / (2 scale) pixels.
    let min_scale = screen_px / (2.0 * short * hi);
    if *scale < min_scale {
        *scale = min_scale;
    }
    let px_per_repeat = screen_px / (2.0 * *scale);
    let mut side = long;
    while px_per_repeat / side < lo && side / 2.0 >= MIN_TEXTURE_PX {
        side /= 2.0;
    }
    *texture_px = (side < long).then(|| side.ceil() as u32);
    let largest = axes.iter().copied().fold(0.0, f64::max);
    if largest > 0.0 && axes.iter().any(|a| (a / largest - 1.0).abs() > 1e-9) {
        *stretch = Some(axes.map(|a| a / largest));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn photo(scale: f64) -> BaseColor {
        BaseColor::Image {
            path: "p.png".into(),
            scale,
            rotation: 0.0,
            fallback: [0.5; 3],
            texture_px: None,
            stretch: None,
        }
    }

    fn parts(b: &BaseColor) -> (f64, Option<u32>, Option<[f64; 3]>) {
        match b {
            BaseColor::Image {
                scale,
                texture_px,
                stretch,
                ..
            } => (*scale, *texture_px, *stretch),
            _ => unreachable!(),
        }
    }

    #[test]
    fn a_small_photo_on_a_large_wall_is_tiled_not_stretched() {
        // 512 px photo once across a 1100 px wall: 2.1 screen px per texel, over the 1.5 limit.
        let mut b = photo(0.5);
        size_photo(&mut b, [512, 512], 1100.0, [1.0; 3], [0.5, 1.5]);
        let (scale, mip, _) = parts(&b);
        let texel = 1100.0 / (2.0 * scale) / 512.0;
        assert!((texel - 1.5).abs() < 1e-9, "{texel}");
        assert_eq!(mip, None);
    }

    #[test]
    fn a_strongly_minified_photo_gets_a_mip_level() {
        // 30 repeats per unit on a 100 px object: 1.7 px per repeat of a 512 px photo.
        let mut b = photo(30.0);
        size_photo(&mut b, [512, 384], 100.0, [1.0; 3], [0.5, 1.5]);
        let (scale, mip, stretch) = parts(&b);
        assert_eq!(scale, 30.0, "repeats kept: the pattern stays repetitive");
        let side = mip.unwrap();
        assert_eq!(side, 8, "halved down to the smallest copy");
        assert_eq!(stretch, None);
        let mut b = photo(2.0);
        size_photo(&mut b, [512, 512], 200.0, [1.0; 3], [0.5, 1.5]);
        // 50 px per repeat: 512 -> 256 -> 128 -> 64 leaves 0.78 px per texel >= 0.5.
        assert_eq!(parts(&b).1, Some(64));
    }

    #[test]
    fn texels_stay_square_on_stretched_objects_and_procedural_bases_are_untouched() {
        let mut b = photo(3.0);
        size_photo(&mut b, [256, 256], 300.0, [2.0, 1.0, 1.0], [0.5, 1.5]);
        assert_eq!(parts(&b).2, Some([1.0, 0.5, 0.5]));
        let mut flat = BaseColor::Flat { color: [0.1; 3] };
        size_photo(&mut flat, [256, 256], 300.0, [1.0; 3], [0.5, 1.5]);
        assert_eq!(flat, BaseColor::Flat { color: [0.1; 3] });
    }
}
