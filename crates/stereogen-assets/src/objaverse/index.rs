//! The Objaverse 1.0 index as the dataset publishes it: `object-paths.json.gz` (uid → path of the
//! GLB, `glbs/<shard>/<uid>.glb`) and one annotation file per shard, `metadata/<shard>.json.gz`
//! (uid → Sketchfab annotation: `name`, `license`, `user`, `viewerUrl`, `categories`, `tags`).

use std::collections::BTreeMap;
use std::io::Read;

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

/// A name-bearing entry of an annotation's `categories` or `tags`.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct Named {
    #[serde(default)]
    pub name: String,
    #[serde(default)]
    pub slug: Option<String>,
}

#[derive(Debug, Clone, Default, Deserialize)]
pub struct User {
    #[serde(default)]
    pub username: String,
}

/// The fields of an annotation a fetch uses (the rest are ignored).
#[derive(Debug, Clone, Default, Deserialize)]
pub struct Annotation {
    #[serde(default)]
    pub name: String,
    #[serde(default)]
    pub license: Option<String>,
    #[serde(default)]
    pub user: Option<User>,
    #[serde(default, rename = "viewerUrl")]
    pub viewer_url: Option<String>,
    #[serde(default)]
    pub categories: Vec<Named>,
    #[serde(default)]
    pub tags: Vec<Named>,
}

impl Annotation {
    /// Whether any category or tag matches one of `wanted` (case-insensitive; empty: all).
    pub fn in_categories(&self, wanted: &[String]) -> bool {
        wanted.is_empty()
            || self.categories.iter().chain(&self.tags).any(|n| {
                wanted.iter().any(|w| {
                    w.eq_ignore_ascii_case(&n.name)
                        || n.slug.as_deref().is_some_and(|s| w.eq_ignore_ascii_case(s))
                })
            })
    }
}

/// What a fetched object records beside its GLB (`<uid>.json`): where it came from, its
/// licence, and the checksum of the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObjectRecord {
    pub uid: String,
    pub name: String,
    /// Sketchfab licence slug (`cc0`, `by`, `by-sa`, ...).
    pub licence: String,
    pub author: Option<String>,
    pub source: Option<String>,
    pub url: String,
    pub sha256: String,
    pub bytes: u64,
}

pub fn gunzip_json<T: for<'de> Deserialize<'de>>(bytes: &[u8], what: &str) -> anyhow::Result<T> {
    let mut text = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut text)
        .with_context(|| format!("{what}: not a gzip file"))?;
    serde_json::from_slice(&text)
        .with_context(|| format!("{what}: not the JSON Objaverse publishes"))
}

/// uid → shard (`000-023`) and path, from `object-paths.json.gz`.
pub fn parse_object_paths(bytes: &[u8]) -> anyhow::Result<BTreeMap<String, (String, String)>> {
    let paths: BTreeMap<String, String> = gunzip_json(bytes, "object-paths.json.gz")?;
    let mut out = BTreeMap::new();
    for (uid, path) in paths {
        let mut parts = path.split('/');
        let (Some(_), Some(shard), Some(_)) = (parts.next(), parts.next(), parts.next()) else {
            bail!("object-paths.json.gz: {uid} has path {path:?}, not glbs/<shard>/<uid>.glb");
        };
        if !path.ends_with(".glb") || !uid.chars().all(|c| c.is_ascii_alphanumeric()) {
            bail!("object-paths.json.gz: {uid} has path {path:?}, not glbs/<shard>/<uid>.glb");
        }
        out.insert(uid, (shard.to_string(), path));
    }
    Ok(out)
}
