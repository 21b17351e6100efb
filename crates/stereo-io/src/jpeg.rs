//! JPEG through libjpeg-turbo's codec, so our pixels are the ones every reference pipeline sees.
//!
//! PIL and OpenCV both decode with libjpeg-turbo and agree exactly; the pure-Rust decoder behind
//! the `image` crate does not (up to 4 levels on 4:2:0 photos at quality 95, more on noise), so
//! a trainer fed through it would see other pixels than the release's own loader. The `mozjpeg`
//! crate builds libjpeg-turbo's fork from vendored C with `cc` (no nasm, no cmake) and its decoder
//! is libjpeg-turbo's: the accurate integer IDCT (`JDCT_ISLOW`) and "fancy" (triangle-filter)
//! chroma upsampling, both libjpeg's defaults and what PIL and OpenCV use. The measurements are
//! in the stereo-io README section on formats and in `tests/integration/conformance.rs` (OpenCV
//! and Pillow decode our JPEGs; we decode OpenCV's).
//!
//! Errors: libjpeg's fatal errors become an error naming the file; of its warnings, a file that
//! ends before its image data does is an error too (its missing rows would be made up), while
//! the recoverable ones ("extraneous bytes before marker", …) are ignored, as PIL and OpenCV do.
//!
//! Writing uses libjpeg-turbo's own settings (`JCP_FASTEST`: baseline, the IJG quantisation
//! tables scaled by quality, as `cv2.imwrite` and PIL write) with Huffman tables optimised per
//! image, and the chroma sampling the caller chooses.

use std::ffi::c_int;
use std::fmt;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::path::Path;
use std::str::FromStr;

use mozjpeg::{ColorSpace, Compress, Decompress};
use mozjpeg_sys::{JWRN_JPEG_EOF, jpeg_common_struct, jpeg_error_mgr};

use crate::error::{Error, Result};
use crate::images::{Image, RgbImage, Samples, image_err};

/// Whether `bytes` start like a JPEG file (SOI marker and the next marker's first byte).
pub fn is_jpeg(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0xFF, 0xD8, 0xFF])
}

/// How the two chroma channels are sampled relative to luma.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChromaSampling {
    /// 4:4:4, every pixel keeps its colour.
    #[default]
    Full,
    /// 4:2:0, one colour sample per 2×2 pixels (`cv2.imwrite`'s and PIL's default).
    Half,
}

impl ChromaSampling {
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "444",
            Self::Half => "420",
        }
    }
}

impl fmt::Display for ChromaSampling {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ChromaSampling {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.replace(':', "").as_str() {
            "444" => Ok(Self::Full),
            "420" => Ok(Self::Half),
            _ => Err(format!("unknown chroma sampling {s:?} (444 or 420)")),
        }
    }
}

/// How a JPEG is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JpegOptions {
    /// 1..=100, libjpeg's scale of the IJG quantisation tables.
    pub quality: u8,
    pub chroma: ChromaSampling,
}

impl Default for JpegOptions {
    /// Quality 95 with full-resolution colour: near-lossless for training images.
    fn default() -> Self {
        Self {
            quality: 95,
            chroma: ChromaSampling::Full,
        }
    }
}

/// The message of a libjpeg error, carried by the unwind out of the C code.
struct JpegFailure(String);

fn message(cinfo: &mut jpeg_common_struct) -> String {
    // SAFETY: libjpeg calls the handlers with `err` pointing at the manager installed below;
    // `format_message` writes at most JMSG_LENGTH_MAX (80) bytes, NUL-terminated, into the
    // buffer. mozjpeg-sys declares that buffer `&[u8; 80]` though libjpeg writes it, so it is
    // passed as the mutable buffer it is.
    unsafe {
        let Some(format) = cinfo.err.as_ref().and_then(|e| e.format_message) else {
            return "libjpeg error".into();
        };
        type Format = unsafe extern "C-unwind" fn(&mut jpeg_common_struct, &mut [u8; 80]);
        let format: Format = std::mem::transmute::<
            unsafe extern "C-unwind" fn(&mut jpeg_common_struct, &[u8; 80]),
            Format,
        >(format);
        let mut buffer = [0u8; 80];
        format(cinfo, &mut buffer);
        let text = buffer.split(|&b| b == 0).next().unwrap_or_default();
        String::from_utf8_lossy(text).into_owned()
    }
}

extern "C-unwind" fn fail(cinfo: &mut jpeg_common_struct) {
    resume_unwind(Box::new(JpegFailure(message(cinfo))));
}

extern "C-unwind" fn on_message(cinfo: &mut jpeg_common_struct, level: c_int) {
    // SAFETY: see `message`.
    let code = unsafe { cinfo.err.as_ref().map_or(0, |e| e.msg_code) };
    if level < 0 && code == JWRN_JPEG_EOF as c_int {
        resume_unwind(Box::new(JpegFailure(
            "the file ends before its image data does (truncated)".into(),
        )));
    }
}

fn error_manager() -> jpeg_error_mgr {
    // SAFETY: `jpeg_std_error` fills every field of the zeroed manager.
    let mut err: jpeg_error_mgr = unsafe { std::mem::zeroed() };
    unsafe { mozjpeg_sys::jpeg_std_error(&mut err) };
    err.error_exit = Some(fail);
    err.emit_message = Some(on_message);
    err
}

/// Runs libjpeg code, turning its unwinding errors into a message.
fn guarded<T>(f: impl FnOnce() -> std::io::Result<T>) -> std::result::Result<T, String> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(e.to_string()),
        Err(payload) => match payload.downcast::<JpegFailure>() {
            Ok(failure) => Err(failure.0),
            Err(other) => resume_unwind(other),
        },
    }
}

/// Decodes a JPEG: grey files to 1 channel, colour (YCbCr or RGB) files to 3. `path` names the
/// file in errors.
pub fn decode_jpeg(bytes: &[u8], path: &Path) -> Result<Image> {
    guarded(|| {
        let dec = Decompress::with_err(error_manager()).from_mem(bytes)?;
        let (width, height) = dec.size();
        // The header's size, checked before libjpeg allocates its buffers for it.
        if let Some(problem) = crate::limits::image_size_problem(width as u64, height as u64) {
            return Err(std::io::Error::other(problem));
        }
        let (channels, mut started) = match dec.color_space() {
            ColorSpace::JCS_GRAYSCALE => (1, dec.grayscale()?),
            ColorSpace::JCS_YCbCr | ColorSpace::JCS_RGB => (3, dec.rgb()?),
            other => {
                return Err(std::io::Error::other(format!(
                    "{other:?} JPEGs are not supported (grey or colour only)"
                )));
            }
        };
        let data: Vec<u8> = started.read_scanlines()?;
        started.finish()?;
        Ok(Image {
            width,
            height,
            channels,
            samples: Samples::U8(data),
        })
    })
    .map_err(|m| image_err(path, format!("JPEG: {m}")))
}

/// Encodes an RGB8 image as a baseline JPEG.
pub fn encode_jpeg_rgb(img: &RgbImage, opts: JpegOptions) -> std::result::Result<Vec<u8>, String> {
    if !(1..=100).contains(&opts.quality) {
        return Err(format!("JPEG quality {} is outside 1..=100", opts.quality));
    }
    if img.data.len() != img.width * img.height * 3
        || img.width == 0
        || img.height == 0
        || img.width.max(img.height) > 65_500
    {
        return Err(format!(
            "a {}x{} image with {} bytes cannot be a JPEG",
            img.width,
            img.height,
            img.data.len()
        ));
    }
    guarded(|| {
        let mut comp = Compress::new_err(Box::new(error_manager()), ColorSpace::JCS_RGB);
        comp.set_fastest_defaults();
        comp.set_size(img.width, img.height);
        comp.set_quality(f32::from(opts.quality));
        comp.set_optimize_coding(true);
        let pixel = match opts.chroma {
            ChromaSampling::Full => (1, 1),
            ChromaSampling::Half => (2, 2),
        };
        comp.set_chroma_sampling_pixel_sizes(pixel, pixel);
        let mut started = comp.start_compress(Vec::with_capacity(img.data.len() / 4))?;
        started.write_scanlines(&img.data)?;
        started.finish()
    })
}

/// Writes an RGB8 JPEG atomically.
pub fn write_jpeg(path: &Path, img: &RgbImage, opts: JpegOptions) -> Result<()> {
    let bytes = encode_jpeg_rgb(img, opts).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)
}

/// The chroma sampling of a JPEG's colour components, from its frame header, where it is one
/// of [`ChromaSampling`]'s.
pub fn chroma_sampling(bytes: &[u8]) -> Option<ChromaSampling> {
    let dec = guarded(|| Decompress::with_err(error_manager()).from_mem(bytes)).ok()?;
    let comps = dec.components();
    if comps.len() != 3 {
        return None;
    }
    let (y, cb, cr) = (&comps[0], &comps[1], &comps[2]);
    let same = cb.h_samp_factor == 1
        && cb.v_samp_factor == 1
        && cr.h_samp_factor == 1
        && cr.v_samp_factor == 1;
    match (same, y.h_samp_factor, y.v_samp_factor) {
        (true, 1, 1) => Some(ChromaSampling::Full),
        (true, 2, 2) => Some(ChromaSampling::Half),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize) -> RgbImage {
        let mut s = 12345u32;
        let data = (0..w * h * 3)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 24) as u8
            })
            .collect();
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn round_trip_keeps_size_and_chroma_sampling() {
        let img = noise(37, 21);
        for chroma in [ChromaSampling::Full, ChromaSampling::Half] {
            let bytes = encode_jpeg_rgb(
                &img,
                JpegOptions {
                    quality: 90,
                    chroma,
                },
            )
            .unwrap();
            assert!(is_jpeg(&bytes));
            assert_eq!(chroma_sampling(&bytes), Some(chroma));
            let back = decode_jpeg(&bytes, Path::new("x.jpg")).unwrap();
            assert_eq!((back.width, back.height, back.channels), (37, 21, 3));
        }
        assert!(
            encode_jpeg_rgb(
                &img,
                JpegOptions {
                    quality: 0,
                    chroma: ChromaSampling::Full
                }
            )
            .is_err()
        );
    }

    #[test]
    fn truncated_and_broken_files_are_errors_naming_the_file() {
        let bytes = encode_jpeg_rgb(&noise(64, 64), JpegOptions::default()).unwrap();
        let e = decode_jpeg(&bytes[..bytes.len() / 2], Path::new("cut.jpg"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cut.jpg") && e.contains("truncated"), "{e}");
        let mut broken = bytes.clone();
        broken[2..40].fill(0x55);
        let e = decode_jpeg(&broken, Path::new("bad.jpg"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.jpg") && e.contains("JPEG"), "{e}");
    }

    #[test]
    fn chroma_names_parse() {
        assert_eq!("4:2:0".parse::<ChromaSampling>(), Ok(ChromaSampling::Half));
        assert_eq!("444".parse::<ChromaSampling>(), Ok(ChromaSampling::Full));
        assert!("422".parse::<ChromaSampling>().is_err());
    }
}
