//! `stereogen export`: a dataset in another trainer's layout. The source is ours or any layout
//! stereo-io reads; the writing is stereo-io's ([`stereo_io::datasets::write`] describes the
//! layouts, what is linked and what is dropped).

use std::path::PathBuf;

use stereo_io::{
    ChromaSampling, DatasetFormat, ImageEncoding, JpegOptions, MiddleburyVariant, ReadOptions,
    WritableFormat, WriteSummary,
};

#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub dataset: PathBuf,
    /// The source's layout; recognised from its folder when `None`.
    pub from: Option<DatasetFormat>,
    pub format: WritableFormat,
    pub out: PathBuf,
    /// CREStereo only: re-encode every image as a JPEG of this quality (else source JPEGs are
    /// linked and other images encoded at quality 95).
    pub jpeg_quality: Option<u8>,
    /// CREStereo only: the chroma sampling of the JPEGs written.
    pub jpeg_chroma: ChromaSampling,
    /// Which rectification of a Middlebury 2014 source is read.
    pub middlebury_variant: MiddleburyVariant,
}

/// Writes every sample of `opts.dataset` into `opts.out` in `opts.format`, with
/// `stereogen_samples.tsv` mapping the exported samples back to the source's.
pub fn export(opts: &ExportOptions) -> anyhow::Result<WriteSummary> {
    let images = match (opts.jpeg_quality, opts.jpeg_chroma) {
        (None, ChromaSampling::Full) => ImageEncoding::Lossless,
        (quality, chroma) => ImageEncoding::JpegWith(JpegOptions {
            quality: quality.unwrap_or(JpegOptions::default().quality),
            chroma,
        }),
    };
    let read = ReadOptions {
        middlebury_variant: opts.middlebury_variant,
    };
    let to = stereo_io::ExportOptions {
        from: opts.from,
        to: opts.format,
        images,
        read,
    };
    Ok(stereo_io::export_dataset(&opts.dataset, &opts.out, &to)?)
}
