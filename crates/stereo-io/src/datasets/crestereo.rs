//! CREStereo's release layout: `<prefix>_left.jpg`, `<prefix>_right.jpg`,
//! `<prefix>_left.disp.png`, `<prefix>_right.disp.png` (16-bit, d·32, 0 = invalid), anywhere
//! below the root. The official loader globs `**/*_left.jpg` and cuts the name at its last `_`;
//! other popular loaders list the release's four category folders ([`CATEGORIES`]) one by one
//! and fail on a missing folder, so the writer creates all four, empty where no sample has that
//! category. Images are real JPEGs (a strict decoder refuses PNG bytes under a `.jpg` name).

use std::path::{Path, PathBuf};

use super::scan::{file_name, rel_id, require, walk};
use super::write::{
    DatasetWriter, ImageEncoding, ImageFile, WriteSummary, mkdir, place_image, sniff, under,
    write_png16, write_right_disparity,
};
use super::{DispKind, SampleFiles, SampleMeta, StereoSample};
use crate::error::Result;
use crate::png_disp::CRESTEREO_SCALE;

/// What names a sample's left image; also how the layout is recognised.
pub const LEFT_IMAGE_SUFFIX: &str = "_left.jpg";
pub const RIGHT_IMAGE_SUFFIX: &str = "_right.jpg";
pub const LEFT_DISPARITY_SUFFIX: &str = "_left.disp.png";
pub const RIGHT_DISPARITY_SUFFIX: &str = "_right.disp.png";

/// The release's category folders (ours are named after them).
pub const CATEGORIES: [&str; 4] = ["tree", "shapenet", "reflective", "hole"];

/// The files of the sample at `prefix` (a path without the suffixes).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CrestereoPaths {
    pub left: PathBuf,
    pub right: PathBuf,
    pub disp_left: PathBuf,
    pub disp_right: PathBuf,
}

impl CrestereoPaths {
    pub fn new(prefix: &Path) -> Self {
        let with = |suffix: &str| {
            let mut name = prefix.as_os_str().to_owned();
            name.push(suffix);
            PathBuf::from(name)
        };
        Self {
            left: with(LEFT_IMAGE_SUFFIX),
            right: with(RIGHT_IMAGE_SUFFIX),
            disp_left: with(LEFT_DISPARITY_SUFFIX),
            disp_right: with(RIGHT_DISPARITY_SUFFIX),
        }
    }
}

pub(crate) fn scan(root: &Path) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for e in walk(root, 8) {
        let name = file_name(e.path());
        let Some(stem) = name.strip_suffix(LEFT_IMAGE_SUFFIX) else {
            continue;
        };
        let prefix = e.path().parent().unwrap_or(root).join(stem);
        let paths = CrestereoPaths::new(&prefix);
        let right = require(paths.right, "right image", e.path())?;
        let disp = require(paths.disp_left, "left disparity", e.path())?;
        out.push(SampleFiles {
            id: rel_id(root, &prefix),
            left: paths.left,
            right,
            disp_left: (disp, DispKind::Png16(CRESTEREO_SCALE)),
            disp_right: paths
                .disp_right
                .is_file()
                .then_some((paths.disp_right, DispKind::Png16(CRESTEREO_SCALE))),
            masks: vec![],
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

/// Writes samples as `<root>/<name>_left.jpg`, … (ours are named `<category>/<id>`), with the
/// four [`CATEGORIES`] folders always present. Images are real JPEGs: with
/// [`ImageEncoding::Lossless`] a source JPEG is linked as it is and any other image encoded with
/// [`JpegOptions::default`](crate::jpeg::JpegOptions); the JPEG encodings re-encode every image.
pub struct CrestereoWriter {
    root: PathBuf,
    images: ImageEncoding,
    summary: WriteSummary,
}

impl CrestereoWriter {
    pub fn new(root: &Path, images: ImageEncoding) -> Result<Self> {
        for category in CATEGORIES {
            mkdir(&root.join(category))?;
        }
        Ok(Self {
            root: root.to_path_buf(),
            images,
            summary: WriteSummary {
                empty_categories: CATEGORIES.to_vec(),
                ..Default::default()
            },
        })
    }

    /// One view's image: linked where the source is a JPEG and no re-encoding was asked for.
    fn place(
        &mut self,
        source: &Path,
        pixels: &crate::image_io::RgbImage,
        dst: &Path,
    ) -> Result<()> {
        let encoding = match self.images {
            ImageEncoding::Lossless
                if !source.as_os_str().is_empty() && sniff(source) == ImageFile::Jpeg =>
            {
                ImageEncoding::Lossless
            }
            other => ImageEncoding::JpegWith(other.jpeg_options().unwrap_or_default()),
        };
        place_image(
            source,
            pixels,
            dst,
            &[ImageFile::Jpeg],
            encoding,
            &mut self.summary,
        )
    }
}

/// Whether a sample named `name` lands in one of the release's category folders (the loaders
/// that list those folders see only such samples).
pub fn in_category_folder(name: &str) -> bool {
    name.split_once('/')
        .is_some_and(|(first, _)| CATEGORIES.contains(&first))
}

impl DatasetWriter for CrestereoWriter {
    fn summary(&self) -> &WriteSummary {
        &self.summary
    }

    fn write(&mut self, _n: usize, name: &str, s: &StereoSample) -> Result<()> {
        let paths = CrestereoPaths::new(&under(&self.root, name)?);
        mkdir(paths.left.parent().unwrap_or(&self.root))?;
        self.place(&s.meta.left_path, &s.left, &paths.left)?;
        self.place(&s.meta.right_path, &s.right, &paths.right)?;
        write_png16(
            &paths.disp_left,
            &s.disp_left,
            CRESTEREO_SCALE,
            &mut self.summary,
        )?;
        write_right_disparity(&paths.disp_right, s, &mut self.summary, |d, sum| {
            write_png16(&paths.disp_right, d, CRESTEREO_SCALE, sum)
        })?;
        self.summary.outside_categories += usize::from(!in_category_folder(name));
        if let Some((category, _)) = name.split_once('/') {
            self.summary.empty_categories.retain(|c| *c != category);
        }
        self.summary.samples += 1;
        Ok(())
    }
}
