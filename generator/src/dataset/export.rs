//! `stereogen export`: a dataset in another trainer's layout. The source is ours or any layout
//! stereo-io reads; the writing is stereo-io's ([`stereo_io::datasets::write`] describes the
//! layouts, what is linked and what is dropped).

use std::path::PathBuf;

use stereo_io::{DatasetFormat, ImageEncoding, WritableFormat, WriteSummary};

#[derive(Debug, Clone)]
pub struct ExportOptions {
    pub dataset: PathBuf,
    /// The source's layout; recognised from its folder when `None`.
    pub from: Option<DatasetFormat>,
    pub format: WritableFormat,
    pub out: PathBuf,
    /// CREStereo only: write real JPEGs with this quality instead of linking the source images.
    pub jpeg_quality: Option<u8>,
}

/// Writes every sample of `opts.dataset` into `opts.out` in `opts.format`, with
/// `stereogen_samples.tsv` mapping the exported samples back to the source's.
pub fn export(opts: &ExportOptions) -> anyhow::Result<WriteSummary> {
    let images = opts.jpeg_quality.map_or(ImageEncoding::Lossless, ImageEncoding::Jpeg);
    let to = stereo_io::ExportOptions { from: opts.from, to: opts.format, images };
    Ok(stereo_io::export_dataset(&opts.dataset, &opts.out, &to)?)
}
