//! Converting a dataset: any layout [`open_dataset`] reads, written in a layout that has a
//! writer, with an index of where each sample came from; and [`create_writer`], the writer of
//! each layout:
//!
//! | layout | writer | files of one sample |
//! | --- | --- | --- |
//! | `crestereo` | [`CrestereoWriter`] | `<category>/<name>_left.jpg`, `_right.jpg` (real JPEG), `_left.disp.png`, `_right.disp.png` (d·32) |
//! | `kitti2012` | [`KittiWriter`] | `training/colored_0/NNNNNN_10.png`, `colored_1/`, `disp_occ/`, `disp_noc/` (d·256) |
//! | `kitti2015` | [`KittiWriter`] | `training/image_2/NNNNNN_10.png`, `image_3/`, `disp_occ_0/`, `disp_noc_0/` (d·256) |
//! | `middlebury` | [`MiddleburyWriter`] | `Middlebury2014/train/<name>-perfect/im0.png`, `im1.png`, `disp0.pfm`, `disp1.pfm`, `calib.txt` |

use std::path::Path;

use super::crestereo::CrestereoWriter;
use super::kitti::{KITTI_2012, KITTI_2015, KittiWriter};
use super::middlebury::MiddleburyWriter;
use super::write::{DatasetWriter, ImageEncoding, WritableFormat, WriteSummary, mkdir};
use super::{DatasetFormat, ReadOptions, SampleMeta, open_dataset_with};
use crate::error::{Error, Result};

/// The index an export writes beside the samples: one line per sample, `n` (its number in the
/// output, KITTI's file number), the source's category (ours; empty for other layouts) and id,
/// tab-separated.
pub const EXPORT_INDEX_FILE: &str = "stereogen_samples.tsv";

#[derive(Debug, Clone, PartialEq)]
pub struct ExportOptions {
    /// The source's layout; recognised from its folder when `None`.
    pub from: Option<DatasetFormat>,
    pub to: WritableFormat,
    pub images: ImageEncoding,
    /// Choices of the source's layout (which Middlebury variant).
    pub read: ReadOptions,
}

/// The samples an export takes: those with these ids (a `--where` of the caller's), described
/// for messages and an export's resume record.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleSelection {
    pub ids: std::collections::BTreeSet<String>,
    pub description: String,
}

impl SampleSelection {
    /// The positions of `dataset`'s samples in the selection (all without one), in order.
    pub(crate) fn positions(
        selection: Option<&Self>,
        dataset: &dyn super::StereoDataset,
    ) -> Vec<usize> {
        (0..dataset.len())
            .filter(|&n| {
                selection.is_none_or(|s| dataset.id(n).is_some_and(|id| s.ids.contains(id)))
            })
            .collect()
    }
}

/// The name a sample gets in the output: ours keep `<category>/<id>`; others are named by their
/// id (a path below the source root) made flat, without the image extension, so the output
/// holds none of the folder names by which the source's layout is recognised.
pub(crate) fn export_name(format: DatasetFormat, meta: &SampleMeta) -> String {
    match (format, meta.extra.get("category")) {
        (DatasetFormat::Stereogen, Some(category)) => format!("{category}/{}", meta.id),
        _ => {
            let id = meta.id.trim_end_matches(".png").trim_end_matches(".jpg");
            id.replace(['/', '\\'], "_")
        }
    }
}

/// Writes every sample of the dataset at `source` into `out` as `opts.to`; returns what was written.
///
/// Each sample is all-or-nothing: its files are written and synced under temporary names and
/// renamed into place together ([`crate::atomic::Batch`]). Re-running into the same `out` is
/// safe: samples already there are replaced by the same files (links to the same source file are
/// left as they are), and temporary files of an export that was killed are removed first. When a
/// sample fails, the export stops; the error says what `out` holds (the samples before it, listed
/// in [`EXPORT_INDEX_FILE`], and nothing of the failed one).
pub fn export_dataset(source: &Path, out: &Path, opts: &ExportOptions) -> Result<WriteSummary> {
    export_selected(source, out, opts, None)
}

/// [`export_dataset`] of the samples in `selection` only, numbered from 0 in the output.
pub fn export_selected(
    source: &Path,
    out: &Path,
    opts: &ExportOptions,
    selection: Option<&SampleSelection>,
) -> Result<WriteSummary> {
    if !source.is_dir() {
        return Err(Error::format(
            source,
            "no such dataset directory (a stereogen dataset holds manifest.jsonl; the other layouts are listed by `open_dataset`)",
        ));
    }
    if out
        .canonicalize()
        .ok()
        .is_some_and(|o| source.canonicalize().ok().is_some_and(|s| o == s))
    {
        return Err(Error::format(
            out,
            "the output must differ from the dataset directory",
        ));
    }
    let dataset = open_dataset_with(source, opts.from, &opts.read)?;
    let mut writer = create_writer(opts.to, out, opts.images)?;
    crate::atomic::remove_orphaned_temp_files(out);
    let mut index = String::new();
    let chosen = SampleSelection::positions(selection, dataset.as_ref());
    for (n, &k) in chosen.iter().enumerate() {
        let exported = dataset.sample(k).and_then(|sample| {
            let name = export_name(dataset.format(), &sample.meta);
            let batch = crate::atomic::Batch::begin();
            writer.write(n, &name, &sample)?;
            batch.commit()?;
            let category = sample.meta.extra.get("category").map_or("", String::as_str);
            index.push_str(&format!("{n:06}\t{category}\t{}\n", sample.meta.id));
            Ok(())
        });
        if let Err(e) = exported {
            let listed = crate::atomic::write_bytes_atomically(
                &out.join(EXPORT_INDEX_FILE),
                index.as_bytes(),
            )
            .is_ok();
            let id = dataset.id(k).unwrap_or("?").to_string();
            return Err(Error::format(
                out,
                format!(
                    "export stopped at sample {id} ({} of {}): {e}; left: the {n} sample(s) before it, complete{}, and nothing of {id}; re-run the same command to finish",
                    n + 1,
                    chosen.len(),
                    if listed {
                        format!(" (listed in {EXPORT_INDEX_FILE})")
                    } else {
                        String::new()
                    }
                ),
            ));
        }
    }
    crate::atomic::write_bytes_atomically(&out.join(EXPORT_INDEX_FILE), index.as_bytes())?;
    Ok(writer.summary().clone())
}

/// A writer of `format` creating its files under `root`.
pub fn create_writer(
    format: WritableFormat,
    root: &Path,
    images: ImageEncoding,
) -> Result<Box<dyn DatasetWriter>> {
    if let Some(jpeg) = images.jpeg_options() {
        if format != WritableFormat::Crestereo {
            return Err(Error::format(
                root,
                format!(
                    "the {format} layout stores PNG images; JPEG quality applies to crestereo only"
                ),
            ));
        }
        if !(1..=100).contains(&jpeg.quality) {
            return Err(Error::format(
                root,
                format!("JPEG quality {} is outside 1..=100", jpeg.quality),
            ));
        }
    }
    mkdir(root)?;
    Ok(match format {
        WritableFormat::Crestereo => Box::new(CrestereoWriter::new(root, images)?),
        WritableFormat::Kitti2012 => Box::new(KittiWriter::new(root, KITTI_2012)),
        WritableFormat::Kitti2015 => Box::new(KittiWriter::new(root, KITTI_2015)),
        WritableFormat::Middlebury => Box::new(MiddleburyWriter::new(root)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The export name of a sample of `format` with this id and no other metadata.
    fn name_of(format: DatasetFormat, id: &str) -> String {
        let meta = SampleMeta {
            id: id.into(),
            ..Default::default()
        };
        export_name(format, &meta)
    }

    #[test]
    fn names_keep_our_categories_and_flatten_other_ids() {
        let mut meta = SampleMeta {
            id: "0000003".into(),
            ..Default::default()
        };
        meta.extra.insert("category".into(), "tree".into());
        assert_eq!(export_name(DatasetFormat::Stereogen, &meta), "tree/0000003");
        assert_eq!(
            name_of(
                DatasetFormat::SceneFlow,
                "FlyingThings3D/frames_cleanpass/TRAIN/A/0000/left/0006.png"
            ),
            "FlyingThings3D_frames_cleanpass_TRAIN_A_0000_left_0006"
        );
        assert_eq!(
            name_of(DatasetFormat::Middlebury, "trainingF/Adirondack"),
            "trainingF_Adirondack"
        );
    }

    #[test]
    fn jpeg_quality_is_for_crestereo_only() {
        let dir = tempfile::tempdir().unwrap();
        let e = create_writer(
            WritableFormat::Kitti2015,
            dir.path(),
            ImageEncoding::Jpeg(90),
        )
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("crestereo only"), "{e}");
        assert!(
            create_writer(
                WritableFormat::Crestereo,
                dir.path(),
                ImageEncoding::Jpeg(0)
            )
            .is_err()
        );
    }
}
