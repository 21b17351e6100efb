//! The maps beside the disparity (a recipe's `[render] outputs`) on the page: a section with
//! `stats`' summary of each map and the semantic class table (id, palette colour, name, share of
//! the pixels), and each gallery tile's row of the left view's maps — depth as inverse depth on
//! the disparity ramp (near red, far blue), normals as `(n + 1) / 2` in RGB, instance and
//! semantic ids in the fixed categorical palette; black is no surface (`stereo_io::colormap`).
//! A dataset without maps gets neither.

use stereo_io::MapKind;
use stereo_io::colormap::{
    categorical, colourise_depth, colourise_ids, colourise_normals, hex, inverse_depth_range,
};
use stereo_io::datasets::MapData;
use stereo_io::datasets::stereogen::SemanticClass;

use super::gallery::png_thumbnail;
use crate::dataset::ManifestEntry;
use crate::validate::dataset_files::DatasetFiles;
use crate::validate::stats::maps::MapStats;

/// One class of the semantic maps on the page.
pub struct ClassRow {
    pub id: u16,
    /// `#rrggbb`: its colour in the pictures.
    pub colour: String,
    pub name: String,
    /// Its share of the semantic maps' pixels, where `stats` could read them.
    pub share: String,
}

pub struct MapsSection {
    /// `stats`' line per map.
    pub lines: Vec<String>,
    pub classes: Vec<ClassRow>,
}

/// The section, where the dataset has maps (`stats` found them) or a semantic class table.
pub fn section(classes: &[SemanticClass], stats: Option<&MapStats>) -> Option<MapsSection> {
    if classes.is_empty() && stats.is_none() {
        return None;
    }
    let shares = stats.and_then(|m| m.semantic.as_ref());
    let share = |id: u16| {
        shares
            .and_then(|s| s.classes.iter().find(|c| c.id == id))
            .map_or("-".into(), |c| format!("{:.2}%", 100.0 * c.share))
    };
    let mut rows: Vec<ClassRow> = classes
        .iter()
        .map(|c| ClassRow {
            id: c.id,
            colour: hex(categorical(c.id)),
            name: c.name.clone(),
            share: share(c.id),
        })
        .collect();
    // Ids in the maps that the table does not name, and no surface, where they occur.
    for c in shares.iter().flat_map(|s| &s.classes) {
        if c.pixels > 0 && !classes.iter().any(|k| k.id == c.id) {
            rows.push(ClassRow {
                id: c.id,
                colour: hex(categorical(c.id)),
                name: c.name.clone(),
                share: format!("{:.2}%", 100.0 * c.share),
            });
        }
    }
    rows.sort_by_key(|r| r.id);
    Some(MapsSection {
        lines: stats.map(MapStats::lines).unwrap_or_default(),
        classes: rows,
    })
}

/// The colourised left-view map `kind` of sample `e`.
fn left_map(files: &DatasetFiles, e: &ManifestEntry, kind: MapKind) -> Result<String, String> {
    let key = kind.file_key("left");
    let path = files.path(e, &key);
    let bytes = files.read(e, &key).map_err(|err| err.to_string())?;
    let rgb = match MapData::decode(kind, &bytes, &path).map_err(|err| err.to_string())? {
        MapData::Depth(m) => colourise_depth(&m, inverse_depth_range([&m])),
        MapData::Normals(m) => colourise_normals(&m),
        MapData::Ids(m) => colourise_ids(&m),
    };
    png_thumbnail(rgb, &path)
}

/// The left view's maps of sample `e` (name, data: URI), in [`MapKind::ALL`]'s order; maps that
/// cannot be shown become `problems`.
pub fn thumbnails(
    files: &DatasetFiles,
    e: &ManifestEntry,
    problems: &mut Vec<String>,
) -> Vec<(String, String)> {
    e.files
        .maps()
        .into_iter()
        .filter(|&k| e.files.map(k, "left").is_some())
        .filter_map(|k| match left_map(files, e, k) {
            Ok(uri) => Some((k.name().to_string(), uri)),
            Err(p) => {
                problems.push(p);
                None
            }
        })
        .collect()
}
