//! Writing samples in another trainer's layout: what the writers have in common — the
//! [`DatasetWriter`] trait each layout's writer implements (beside its reader, sharing its file
//! names), the image encoding, the summary, and the file placement. Which writer a layout gets
//! is decided one floor up, in [`create_writer`](super::export::create_writer).
//!
//! Our own layout is written by the generator (it renders; it does not convert).
//!
//! Images: where the sample's source file ([`SampleMeta::left_path`](super::SampleMeta)) is
//! already encoded as the layout stores it, it is hard-linked (copied across filesystems);
//! otherwise the decoded pixels are encoded. Disparity: what a 16-bit PNG cannot hold (negative,
//! or at or above 65535.5/scale) is stored as invalid and counted. A sample without a right-view
//! disparity is written without the right-view disparity file (every layout here has it
//! optional), and counted. Every file appears atomically, so an interrupted write can be re-run.

use std::fmt;
use std::io::Read;
use std::path::{Component, Path, PathBuf};
use std::str::FromStr;

use super::{DatasetFormat, StereoSample};
use crate::disparity::DisparityMap;
use crate::error::{Error, Result};
use crate::image_io::RgbImage;

/// How a writer stores images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ImageEncoding {
    /// The layout's own image format, re-encoding as little as possible: the source file linked
    /// where it already is what the layout stores (an RGB PNG; for CREStereo also a JPEG), else
    /// PNG without loss, or for CREStereo, whose files are JPEG, a real JPEG with
    /// [`JpegOptions::default`](crate::jpeg::JpegOptions) (quality 95, 4:4:4). No file's bytes
    /// differ from what its name says.
    #[default]
    Lossless,
    /// Real JPEGs at this quality (1..=100), 4:4:4; only CREStereo stores JPEG.
    Jpeg(u8),
    /// Real JPEGs with this quality and chroma sampling; only CREStereo stores JPEG.
    JpegWith(crate::jpeg::JpegOptions),
}

impl ImageEncoding {
    /// The JPEG settings of a re-encoding encoding.
    pub fn jpeg_options(self) -> Option<crate::jpeg::JpegOptions> {
        match self {
            Self::Lossless => None,
            Self::Jpeg(quality) => Some(crate::jpeg::JpegOptions {
                quality,
                ..Default::default()
            }),
            Self::JpegWith(opts) => Some(opts),
        }
    }
}

/// What a writer has done so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct WriteSummary {
    pub samples: usize,
    /// Image files that are hard links to the source's.
    pub linked: usize,
    /// Files written (disparities, calibrations, encoded or copied images).
    pub written: usize,
    /// Valid pixels the layout cannot hold, stored as invalid.
    pub dropped_pixels: usize,
    /// Samples written without a right-view disparity: the source has none, or the layout
    /// holds none (KITTI).
    pub without_right_disparity: usize,
    /// CREStereo: samples outside the release's category folders (no category in the source).
    pub outside_categories: usize,
    /// CREStereo: the release's category folders that hold no sample.
    pub empty_categories: Vec<&'static str>,
}

impl WriteSummary {
    /// One line per way the layout written falls short of what common loaders of it expect
    /// (for `export` to print): none when every loader we know reads it whole.
    pub fn loader_notes(&self, format: WritableFormat, out: &Path) -> Vec<String> {
        let mut notes = vec![];
        if format != WritableFormat::Crestereo {
            return notes;
        }
        if self.outside_categories > 0 {
            notes.push(format!(
                "{} sample(s) have no CREStereo category and sit at the top of {}: the release's loader (a recursive glob) reads them, loaders that list tree/, shapenet/, reflective/ and hole/ do not",
                self.outside_categories,
                out.display()
            ));
        }
        if !self.empty_categories.is_empty() && self.samples > 0 {
            notes.push(format!(
                "no sample in {} of {}: torchvision's CREStereo loader needs at least one in each of tree/, shapenet/, reflective/ and hole/ and refuses this export",
                self.empty_categories.join("/, ") + "/",
                out.display()
            ));
        }
        if self.without_right_disparity > 0 {
            notes.push(format!(
                "{} sample(s) have no right-view disparity: torchvision's CREStereo loader pairs *_left.disp.png with *_right.disp.png and refuses this export",
                self.without_right_disparity
            ));
        }
        notes
    }
}

/// A layout being written, one sample at a time.
pub trait DatasetWriter {
    /// Writes `sample` as the `n`-th sample of the output, named `name` (a relative path of
    /// `/`-separated components; the layouts that number their samples use `n` instead).
    fn write(&mut self, n: usize, name: &str, sample: &StereoSample) -> Result<()>;
    fn summary(&self) -> &WriteSummary;
}

/// The layouts that have a writer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WritableFormat {
    Crestereo,
    Kitti2012,
    Kitti2015,
    Middlebury,
}

impl WritableFormat {
    pub const ALL: [WritableFormat; 4] = [
        Self::Crestereo,
        Self::Kitti2012,
        Self::Kitti2015,
        Self::Middlebury,
    ];

    pub fn dataset_format(self) -> DatasetFormat {
        match self {
            Self::Crestereo => DatasetFormat::Crestereo,
            Self::Kitti2012 => DatasetFormat::Kitti2012,
            Self::Kitti2015 => DatasetFormat::Kitti2015,
            Self::Middlebury => DatasetFormat::Middlebury,
        }
    }
}

impl fmt::Display for WritableFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.dataset_format().name())
    }
}

impl FromStr for WritableFormat {
    type Err = String;
    /// A layout name as [`DatasetFormat`] parses it; `kitti` means KITTI 2015.
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let names = || Self::ALL.map(|f| f.to_string()).join(", ");
        let format = if s.eq_ignore_ascii_case("kitti") {
            DatasetFormat::Kitti2015
        } else {
            s.parse::<DatasetFormat>()
                .map_err(|_| format!("unknown layout {s:?} to write (one of: {})", names()))?
        };
        Self::ALL
            .into_iter()
            .find(|f| f.dataset_format() == format)
            .ok_or_else(|| {
                format!(
                    "stereo-io has no writer for the {format} layout (one of: {})",
                    names()
                )
            })
    }
}

pub(crate) fn mkdir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
}

/// `root` joined with a sample name, refusing names that would leave `root`.
pub(crate) fn under(root: &Path, name: &str) -> Result<PathBuf> {
    let rel = Path::new(name);
    if name.is_empty() || !rel.components().all(|c| matches!(c, Component::Normal(_))) {
        return Err(Error::format(
            root,
            format!("sample name {name:?} is not a relative path inside the output"),
        ));
    }
    Ok(root.join(rel))
}

/// How an image file is encoded, from its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ImageFile {
    /// 8-bit RGB PNG: what KITTI and Middlebury store.
    PngRgb8,
    Jpeg,
    Other,
}

pub(crate) fn sniff(path: &Path) -> ImageFile {
    let mut head = [0u8; 26];
    let read = std::fs::File::open(path).and_then(|mut f| f.read_exact(&mut head));
    if read.is_err() {
        return ImageFile::Other;
    }
    const PNG: [u8; 8] = [0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'];
    // IHDR follows the signature: bit depth at byte 24, colour type at 25 (2 = RGB).
    if head[..8] == PNG && &head[12..16] == b"IHDR" && head[24] == 8 && head[25] == 2 {
        ImageFile::PngRgb8
    } else if head[..3] == [0xFF, 0xD8, 0xFF] {
        ImageFile::Jpeg
    } else {
        ImageFile::Other
    }
}

/// Removes what an earlier write left at `path` (a right-view disparity the source now lacks), so
/// the output says what this write wrote; with the sample's other files (see [`crate::atomic::Batch`]).
pub(crate) fn remove_stale(path: &Path) -> Result<()> {
    crate::atomic::remove_file_durably(path)
}

/// Whether `a` and `b` are the same file (one is a hard link of the other).
#[cfg(unix)]
fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_: &Path, _: &Path) -> bool {
    false
}

/// Places `src` at `dst`: a hard link, or a durable copy where the filesystem refuses links;
/// atomically. A `dst` that already is a link of `src` (a re-export) is left as it is.
fn link_or_copy(src: &Path, dst: &Path, summary: &mut WriteSummary) -> Result<()> {
    if same_file(src, dst) {
        summary.linked += 1;
        return Ok(());
    }
    let tmp = crate::atomic::temp_sibling(dst);
    if std::fs::hard_link(src, &tmp).is_ok() {
        summary.linked += 1;
        return crate::atomic::place(&tmp, dst);
    }
    let bytes = std::fs::read(src).map_err(|e| Error::io(src, e))?;
    crate::atomic::write_bytes_atomically(dst, &bytes)?;
    summary.written += 1;
    Ok(())
}

/// Stores one view's image at `dst`: the source file linked if it is one of `linkable`, else
/// the pixels encoded as `encoding` says.
pub(crate) fn place_image(
    source: &Path,
    pixels: &RgbImage,
    dst: &Path,
    linkable: &[ImageFile],
    encoding: ImageEncoding,
    summary: &mut WriteSummary,
) -> Result<()> {
    match encoding {
        ImageEncoding::Lossless
            if !source.as_os_str().is_empty() && linkable.contains(&sniff(source)) =>
        {
            link_or_copy(source, dst, summary)
        }
        ImageEncoding::Lossless => {
            crate::image_io::write_png_rgb(dst, pixels)?;
            summary.written += 1;
            Ok(())
        }
        ImageEncoding::Jpeg(_) | ImageEncoding::JpegWith(_) => {
            crate::jpeg::write_jpeg(
                dst,
                pixels,
                encoding.jpeg_options().expect("a JPEG encoding"),
            )?;
            summary.written += 1;
            Ok(())
        }
    }
}

/// Stores both views of `s` as lossless 8-bit PNGs at `left` and `right` (the layouts whose
/// images are PNG: KITTI, Middlebury), each source file linked where it already is one.
pub(crate) fn place_png_pair(
    s: &StereoSample,
    left: &Path,
    right: &Path,
    summary: &mut WriteSummary,
) -> Result<()> {
    let png = [ImageFile::PngRgb8];
    for (source, pixels, dst) in [
        (&s.meta.left_path, &s.left, left),
        (&s.meta.right_path, &s.right, right),
    ] {
        place_image(source, pixels, dst, &png, ImageEncoding::Lossless, summary)?;
    }
    Ok(())
}

/// `map` with every valid value a 16-bit PNG at `scale` cannot hold made invalid; how many.
pub(crate) fn representable(map: &DisparityMap, scale: f32) -> (DisparityMap, usize) {
    let max = 65535.5 / f64::from(scale);
    let mut out = map.clone();
    let mut dropped = 0;
    for (d, v) in out.data.iter_mut().zip(out.valid.iter_mut()) {
        if *v && !(f64::from(*d) >= 0.0 && f64::from(*d) < max) {
            *v = false;
            *d = 0.0;
            dropped += 1;
        }
    }
    (out, dropped)
}

/// The right view's disparity where the sample has one; without, a stale file is removed and the
/// sample counted.
pub(crate) fn write_right_disparity(
    path: &Path,
    sample: &StereoSample,
    summary: &mut WriteSummary,
    write: impl FnOnce(&DisparityMap, &mut WriteSummary) -> Result<()>,
) -> Result<()> {
    match &sample.disp_right {
        Some(d) => write(d, summary),
        None => {
            remove_stale(path)?;
            summary.without_right_disparity += 1;
            Ok(())
        }
    }
}

/// Writes a 16-bit disparity PNG, dropping (and counting) what it cannot hold.
pub(crate) fn write_png16(
    path: &Path,
    map: &DisparityMap,
    scale: f32,
    summary: &mut WriteSummary,
) -> Result<()> {
    let (map, dropped) = representable(map, scale);
    crate::png_disp::write_disparity_png16(path, &map, scale)?;
    summary.dropped_pixels += dropped;
    summary.written += 1;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_names_parse_and_formats_without_writer_are_named() {
        assert_eq!(
            "kitti".parse::<WritableFormat>(),
            Ok(WritableFormat::Kitti2015)
        );
        assert_eq!(
            "KITTI-2015".parse::<WritableFormat>(),
            Ok(WritableFormat::Kitti2015)
        );
        assert_eq!(
            "middlebury".parse::<WritableFormat>(),
            Ok(WritableFormat::Middlebury)
        );
        let e = "sceneflow".parse::<WritableFormat>().unwrap_err();
        assert!(
            e.contains("no writer for the sceneflow layout")
                && e.contains("crestereo, kitti2012, kitti2015, middlebury"),
            "{e}"
        );
        assert_eq!(
            "kitti2012".parse::<WritableFormat>(),
            Ok(WritableFormat::Kitti2012)
        );
        assert!(
            "pngs"
                .parse::<WritableFormat>()
                .unwrap_err()
                .contains("unknown layout")
        );
    }

    #[test]
    fn names_cannot_leave_the_output() {
        let root = Path::new("/out");
        assert_eq!(
            under(root, "tree/0000001").unwrap(),
            root.join("tree/0000001")
        );
        for bad in ["", "../x", "/etc/x", "a/../../b"] {
            assert!(under(root, bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn unrepresentable_disparities_become_invalid() {
        let map = DisparityMap {
            width: 4,
            height: 1,
            data: vec![255.99, 256.0, -1.0, 3.0],
            valid: vec![true, true, true, false],
        };
        let (out, dropped) = representable(&map, 256.0);
        assert_eq!(dropped, 2);
        assert_eq!(out.valid, vec![true, false, false, false]);
    }
}
