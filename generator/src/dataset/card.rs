//! The dataset card of a WebDataset export (`export --format webdataset`, `merge --webdataset`):
//! `README.md` beside the shards, with the YAML header the Hugging Face Hub reads (licences,
//! task, size, one config whose splits name the shards) and a body that says what the shards
//! hold and how to load them with `datasets`, `webdataset` and `stereogen.torch`.
//!
//! Everything in it comes from the export itself (the index of each split and every sample's
//! `<key>.json`, which for our datasets carries its manifest line) and from the source's
//! `dataset.json` (recipe, seed, version); the licences from the content the recipe draws on:
//! the content pack's files (their pinned licences, the recipe's exclusions applied), an
//! Objaverse folder's records, or a note where a folder's licence is not known.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use stereo_io::datasets::webdataset::members::ShardMembers;
use stereo_io::datasets::webdataset::{CARD_FILE, INDEX_SUFFIX, ShardIndex};
use stereogen_assets::objaverse::ObjectRecord;
use stereogen_assets::pack::{FILES, PACKAGES, PackKind};
use stereogen_plan::Recipe;

mod maps;
use maps::{map_member_row, maps_section};

/// What the shards hold, gathered from the export.
#[derive(Debug, Default)]
struct Contents {
    /// Samples per split and category.
    counts: BTreeMap<String, BTreeMap<String, usize>>,
    /// Image sizes (width, height) and their sample counts.
    sizes: BTreeMap<(u64, u64), usize>,
    /// Shards per split.
    shards: BTreeMap<String, usize>,
    disparity: DisparityTotals,
    /// Members of the first sample (after `<key>.`), as stored.
    members: Vec<String>,
}

/// The left views' disparity over every sample whose manifest line carries its summary.
#[derive(Debug, Default)]
struct DisparityTotals {
    samples: usize,
    min: f64,
    max: f64,
    /// Sum of disparities of the valid pixels, and their number; all pixels.
    sum: f64,
    valid: f64,
    pixels: f64,
    /// Each sample's mean, for the spread across samples.
    means: Vec<f64>,
}

/// One licence the content is used under, and what of it.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
struct LicenceUse {
    /// As the source states it (SPDX, `public-domain`, an Objaverse slug, or `unknown`).
    licence: String,
    what: String,
}

/// Writes `out/README.md` for the WebDataset export in `out`.
pub fn write_card(out: &Path) -> anyhow::Result<()> {
    let card = card_text(out)?;
    stereo_io::atomic::write_bytes_atomically(&out.join(CARD_FILE), card.as_bytes())
        .with_context(|| format!("writing the dataset card into {}", out.display()))
}

fn card_text(out: &Path) -> anyhow::Result<String> {
    let info = read_info(out);
    let contents = read_contents(out)?;
    let licences = match info.as_ref().and_then(|i| i.recipe.as_ref()) {
        Some(recipe) => licences_of(recipe),
        None => vec![LicenceUse {
            licence: "unknown".into(),
            what: "the source dataset's own licence (not one of stereogen's datasets: see where it came from)".into(),
        }],
    };
    Ok(render(info.as_ref(), &contents, &licences))
}

/// `dataset.json` of the source, where it is one of ours.
struct Info {
    seed: u64,
    version: String,
    fingerprint: String,
    recipe: Option<Recipe>,
    recipe_name: String,
    /// The classes of the `semantic_*` maps, where the dataset has them.
    semantic_classes: Vec<stereo_io::datasets::stereogen::SemanticClass>,
}

fn read_info(out: &Path) -> Option<Info> {
    let bytes = std::fs::read(out.join("dataset.json")).ok()?;
    let info: stereo_io::DatasetInfo<serde_json::Value> = serde_json::from_slice(&bytes).ok()?;
    let recipe: Option<Recipe> = serde_json::from_value(info.recipe.clone()).ok();
    let recipe_name = info.recipe["name"].as_str().unwrap_or("custom").to_string();
    Some(Info {
        seed: info.seed,
        version: info.stereogen_version,
        fingerprint: info.recipe_fingerprint,
        recipe,
        recipe_name,
        semantic_classes: info.semantic_classes,
    })
}

fn read_contents(out: &Path) -> anyhow::Result<Contents> {
    let mut c = Contents {
        disparity: DisparityTotals {
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut splits = Vec::new();
    for entry in std::fs::read_dir(out).with_context(|| format!("reading {}", out.display()))? {
        let path = entry?.path();
        let name = path.file_name().unwrap_or_default().to_string_lossy();
        if let Some(split) = name.strip_suffix(INDEX_SUFFIX) {
            let index: ShardIndex = serde_json::from_slice(&std::fs::read(&path)?)
                .with_context(|| format!("reading {}", path.display()))?;
            c.shards.insert(split.to_string(), index.shards.len());
            splits.push(split.to_string());
        }
    }
    splits.sort();
    for split in &splits {
        let members = ShardMembers::open_splits(out, std::slice::from_ref(split))?;
        let counts = c.counts.entry(split.clone()).or_default();
        for i in 0..members.len() {
            if c.members.is_empty() {
                c.members = members.suffixes(i).map(str::to_string).collect();
            }
            let facts: serde_json::Value = match members.read(i, "json")? {
                Some(bytes) => serde_json::from_slice(&bytes).unwrap_or_default(),
                None => serde_json::Value::Null,
            };
            let manifest = &facts["manifest"];
            let category = manifest["category"]
                .as_str()
                .or(facts["extra"]["category"].as_str())
                .unwrap_or("-");
            *counts.entry(category.to_string()).or_default() += 1;
            if let (Some(w), Some(h)) = (manifest["width"].as_u64(), manifest["height"].as_u64()) {
                *c.sizes.entry((w, h)).or_default() += 1;
                let d = &manifest["disparity_left"];
                if let (Some(min), Some(max), Some(mean), Some(valid)) = (
                    d["min"].as_f64(),
                    d["max"].as_f64(),
                    d["mean"].as_f64(),
                    d["valid_fraction"].as_f64(),
                ) {
                    let t = &mut c.disparity;
                    let pixels = (w * h) as f64;
                    t.samples += 1;
                    t.min = t.min.min(min);
                    t.max = t.max.max(max);
                    t.sum += mean * valid * pixels;
                    t.valid += valid * pixels;
                    t.pixels += pixels;
                    t.means.push(mean);
                }
            }
        }
    }
    Ok(c)
}

/// The licences of the content a recipe draws on.
fn licences_of(recipe: &Recipe) -> Vec<LicenceUse> {
    let s = &recipe.sources;
    let mut out = BTreeSet::new();
    let excluded = |l: &str| {
        s.exclude_licences
            .iter()
            .any(|x| x.trim().eq_ignore_ascii_case(l))
    };
    let photos = s.builtin_pack && s.textures.is_none();
    let meshes = s.builtin_pack && s.shapenet.is_none() && s.meshes.is_none();
    let mut pack: BTreeMap<(&str, &str, PackKind), usize> = BTreeMap::new();
    for f in FILES {
        let used = match f.kind {
            PackKind::Photo => photos,
            PackKind::Mesh => meshes,
        };
        if used && !excluded(f.licence) {
            *pack
                .entry((f.licence, PACKAGES[f.package].name, f.kind))
                .or_default() += 1;
        }
    }
    for ((licence, package, kind), n) in pack {
        let version = PACKAGES
            .iter()
            .find(|p| p.name == package)
            .map_or("", |p| p.version);
        let kind = match (kind, n) {
            (PackKind::Photo, 1) => "photo",
            (PackKind::Photo, _) => "photos",
            (PackKind::Mesh, 1) => "mesh",
            (PackKind::Mesh, _) => "meshes",
        };
        out.insert(LicenceUse {
            licence: licence.to_string(),
            what: format!("{n} {kind} of the content pack ({package} {version})"),
        });
    }
    if let Some(dir) = &s.textures {
        out.insert(LicenceUse {
            licence: "unknown".into(),
            what: format!(
                "photos of the texture folder {} (their licence is not recorded: state it)",
                dir.display()
            ),
        });
    }
    if let Some(dir) = &s.meshes {
        let mut slugs: BTreeMap<String, usize> = BTreeMap::new();
        let mut others = 0;
        for entry in walkdir::WalkDir::new(dir).into_iter().flatten() {
            let p = entry.path();
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            if ext.eq_ignore_ascii_case("json") {
                let record = std::fs::read(p)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<ObjectRecord>(&b).ok());
                if let Some(r) = record {
                    *slugs.entry(r.licence).or_default() += 1;
                }
            } else if ["obj", "glb", "gltf", "ply", "stl", "off"]
                .iter()
                .any(|m| ext.eq_ignore_ascii_case(m))
            {
                others += 1;
            }
        }
        let recorded: usize = slugs.values().sum();
        for (slug, n) in slugs {
            out.insert(LicenceUse {
                licence: slug,
                what: format!(
                    "{n} Objaverse object(s) of the mesh folder {} (licence per object in its <uid>.json)",
                    dir.display()
                ),
            });
        }
        if others > recorded {
            out.insert(LicenceUse {
                licence: "unknown".into(),
                what: format!(
                    "meshes of the folder {} without a licence record (state it)",
                    dir.display()
                ),
            });
        }
    }
    if let Some(dir) = &s.shapenet {
        out.insert(LicenceUse {
            licence: "unknown".into(),
            what: format!(
                "ShapeNet models from {} (ShapeNet's terms of use apply)",
                dir.display()
            ),
        });
    }
    let environments = recipe.categories.iter().any(|c| {
        c.background
            .get(&stereogen_plan::BackgroundKind::Environment)
            .is_some_and(|w| *w > 0.0)
    });
    if environments {
        out.insert(LicenceUse {
            licence: "CC0-1.0".into(),
            what: format!(
                "{} HDR environment maps shipped with Blender (Poly Haven, in the bpy wheel)",
                stereogen_plan::STUDIO_HDRIS.len()
            ),
        });
    }
    out.into_iter().collect()
}

/// The Hub's identifier of a licence, where it has one.
fn hub_licence(licence: &str) -> Option<&'static str> {
    Some(match licence.to_ascii_lowercase().as_str() {
        "cc0-1.0" | "cc0" => "cc0-1.0",
        "cc-by-4.0" | "by" => "cc-by-4.0",
        "cc-by-sa-4.0" | "by-sa" => "cc-by-sa-4.0",
        "cc-by-nc-4.0" | "by-nc" => "cc-by-nc-4.0",
        "cc-by-nd-4.0" | "by-nd" => "cc-by-nd-4.0",
        "cc-by-nc-sa-4.0" | "by-nc-sa" => "cc-by-nc-sa-4.0",
        "cc-by-nc-nd-4.0" | "by-nc-nd" => "cc-by-nc-nd-4.0",
        "mit" => "mit",
        "apache-2.0" => "apache-2.0",
        "bsd-3-clause" => "bsd-3-clause",
        _ => return None,
    })
}

fn size_category(n: usize) -> &'static str {
    match n {
        0..1_000 => "n<1K",
        1_000..10_000 => "1K<n<10K",
        10_000..100_000 => "10K<n<100K",
        100_000..1_000_000 => "100K<n<1M",
        _ => "1M<n<10M",
    }
}

fn render(info: Option<&Info>, c: &Contents, licences: &[LicenceUse]) -> String {
    let title = match info {
        Some(i) => format!(
            "stereogen {} stereo dataset (seed {})",
            i.recipe_name, i.seed
        ),
        None => "stereo dataset (WebDataset shards by stereogen)".to_string(),
    };
    let mut s = front_matter(&title, c, licences);
    intro(&mut s, &title, info);
    contents_section(&mut s, c);
    members_section(&mut s, &c.members);
    maps_section(
        &mut s,
        &c.members,
        info.map_or(&[], |i| &i.semantic_classes),
    );
    load_section(&mut s, c);
    licences_section(&mut s, licences);
    s
}

/// The YAML header the Hub reads: licences, title, task, size and the splits' shards.
fn front_matter(title: &str, c: &Contents, licences: &[LicenceUse]) -> String {
    let total: usize = c.counts.values().flat_map(|m| m.values()).sum();
    let mut hub: BTreeSet<&str> = BTreeSet::new();
    let mut other = false;
    for l in licences {
        match hub_licence(&l.licence) {
            Some(id) => {
                hub.insert(id);
            }
            None => other = true,
        }
    }
    let mut s = String::from("---\n");
    if hub.is_empty() && !other {
        // Procedural content only: the licence is the publisher's choice.
        s += "license: other\nlicense_name: choose-before-publishing\n";
    } else {
        s += "license:\n";
        for id in &hub {
            let _ = writeln!(s, "- {id}");
        }
        if other {
            s += "- other\nlicense_name: mixed-see-card\n";
        }
    }
    let _ = writeln!(s, "pretty_name: \"{title}\"");
    s += "task_categories:\n- depth-estimation\ntags:\n- stereo\n- disparity\n- synthetic\n- webdataset\n";
    let _ = writeln!(s, "size_categories:\n- {}", size_category(total));
    s += "configs:\n- config_name: default\n  data_files:\n";
    for split in c.counts.keys() {
        let _ = writeln!(s, "  - split: {split}\n    path: \"{split}-*.tar\"");
    }
    s += "---\n\n";
    s
}

/// The title and what the files are, with how to make them again.
fn intro(s: &mut String, title: &str, info: Option<&Info>) {
    let _ = writeln!(s, "# {title}\n");
    *s += "Stereo pairs with exact float32 disparity for both views, as WebDataset tar shards: the files \
of one sample lie consecutively in a shard under one key (`<key>.left.png`, `<key>.right.png`, \
`<key>.disp_left.exr`, ...).\n\n";
    if let Some(i) = info {
        let _ = writeln!(
            s,
            "Made by stereogen {} from the recipe `{}` (fingerprint `{}`) with seed {}: every sample is a \
function of (recipe, seed, index), so `stereogen generate` with the same recipe and seed makes it again. \
The recipe is in `dataset.json` beside this card.\n",
            i.version, i.recipe_name, i.fingerprint, i.seed
        );
    }
}

/// The splits, their shards and samples, the image sizes and the disparity's range.
fn contents_section(s: &mut String, c: &Contents) {
    *s += "## Contents\n\n| split | shards | samples | per category |\n|---|---:|---:|---|\n";
    for (split, cats) in &c.counts {
        let n: usize = cats.values().sum();
        let per = cats
            .iter()
            .map(|(k, v)| format!("{k} {v}"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "| {split} | {} | {n} | {per} |",
            c.shards.get(split).copied().unwrap_or(0)
        );
    }
    if !c.sizes.is_empty() {
        let sizes = c
            .sizes
            .iter()
            .map(|((w, h), n)| format!("{w}×{h} ({n})"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(s, "\nImage size (width × height, samples): {sizes}.");
    }
    let d = &c.disparity;
    if d.samples > 0 {
        let mut means = d.means.clone();
        means.sort_by(f64::total_cmp);
        let q = |p: f64| means[((means.len() - 1) as f64 * p).round() as usize];
        let _ = writeln!(
            s,
            "\n**Disparity** of the left views, valid pixels of {} samples: {:.3}–{:.3} px, mean {:.3} px; \
per-sample means from {:.3} (min) over {:.3} (median) to {:.3} px (max); {:.2}% of the pixels hold \
ground truth (the others, where no surface was hit, hold 0 and are flagged invalid).",
            d.samples,
            d.min,
            d.max,
            d.sum / d.valid.max(1.0),
            q(0.0),
            q(0.5),
            q(1.0),
            100.0 * d.valid / d.pixels.max(1.0)
        );
    }
}

/// What each member of a sample is and what `datasets` makes of it.
fn members_section(s: &mut String, members: &[String]) {
    *s += "\n## Members of a sample\n\n| member | what | `datasets` gives |\n|---|---|---|\n";
    for m in members {
        let (what, hub_gives) = match m.as_str() {
            "left.png" | "left.jpg" => ("left image, 8-bit RGB", "a PIL image"),
            "right.png" | "right.jpg" => ("right image, 8-bit RGB", "a PIL image"),
            "disp_left.exr" => (
                "left view's disparity, float32 EXR: channel `Y` in pixels (a left pixel at x matches the right one at x − d), channel `valid` 1/0",
                "bytes (not decoded: see below)",
            ),
            "disp_right.exr" => (
                "right view's disparity, same format (a right pixel at x matches the left one at x + d)",
                "bytes (not decoded: see below)",
            ),
            "valid_left.png" => (
                "the source's stricter validity mask of the left view, 255 = keep",
                "a PIL image",
            ),
            "json" => (
                "the sample's facts: id, f_px, baseline_m, principal point, category, and for stereogen's own datasets its manifest line",
                "a dict",
            ),
            "scene.json.gz" | "scene.json" => (
                "the scene specification that renders the sample again (`stereogen render --spec`)",
                "a dict",
            ),
            m => map_member_row(m),
        };
        let _ = writeln!(s, "| `{m}` | {what} | {hub_gives} |");
    }
}

/// How to load the shards with `datasets`, `webdataset` + PyTorch and `stereogen.torch`.
fn load_section(s: &mut String, c: &Contents) {
    let first_shard = |split: &str| format!("{split}-000000.tar");
    let train = c
        .counts
        .keys()
        .find(|k| *k == "train")
        .or(c.counts.keys().next())
        .cloned()
        .unwrap_or_else(|| "train".into());
    let last = c.shards.get(&train).copied().unwrap_or(1).saturating_sub(1);
    let data_files = c
        .counts
        .keys()
        .map(|k| format!("\"{k}\": \"{k}-*.tar\""))
        .collect::<Vec<_>>()
        .join(", ");
    let _ = write!(
        s,
        "
## Load it

The loaders below run in this folder; on the Hub, `load_dataset(\"USER/REPO\")` finds the splits \
through this card's `configs`.

**🤗 `datasets`** (its WebDataset builder decodes the images to PIL and the JSON members to \
dicts; it has no decoder for EXR, so the disparity members arrive as bytes):

```python
from datasets import load_dataset
ds = load_dataset(\"webdataset\", data_files={{{data_files}}})
```

Two lines decode a disparity member into a float32 H×W array in pixels and its validity mask \
(bool H×W), with the `stereogen` Python package (the wheel `maturin build --release` makes in \
stereogen's `crates/stereogen-py`):

```python
import stereogen
disp, valid = stereogen.decode_disparity(row[\"disp_left.exr\"])
```

**`webdataset` + PyTorch**: `stereogen.decode_sample` turns the members of a sample into NumPy \
arrays (what `stereogen.open_dataset(...)[i]` returns) and `stereogen.torch.to_tensors` into \
tensors (left/right float32 3×H×W RGB 0–255, disparity and validity 1×H×W):

```python
import stereogen, stereogen.torch, torch, webdataset as wds
shards = wds.WebDataset(\"{train}-{{000000..{last:06}}}.tar\", shardshuffle=False, empty_check=False)
loader = torch.utils.data.DataLoader(shards.map(stereogen.decode_sample).map(stereogen.torch.to_tensors), batch_size=2, num_workers=2)
```

**`stereogen.torch`** streams the shards itself (split across ranks and DataLoader workers), or \
reads any sample by seeking:

```python
from stereogen.torch import StereoDataset, StereoWebDataset
stream = StereoWebDataset(\".\", split=\"{train}\", shuffle_shards=True, shuffle_buffer=100)
by_index = StereoDataset(\".\")
```

stereogen itself reads the folder as a dataset: `stereogen stats .`, `stereogen report .`, \
`crestereo train --data .:webdataset:{train}`. The first shard of a split is `{first}`; \
`<split>.index.json` lists every shard with its sample count and size.

## Licences

",
        first = first_shard(&train),
    );
}

/// The licences of the content the images show, with attributions.
fn licences_section(s: &mut String, licences: &[LicenceUse]) {
    if licences.is_empty() {
        *s += "Procedural content only: no third-party photo or mesh is in these images. The \
licence is yours to choose: set `license:` in the header before publishing.\n";
    } else {
        *s += "The images show content under these licences (the rendered images are derivative works \
of it; CC-BY content asks for attribution when you publish images that show it):\n\n";
        for l in licences {
            let _ = writeln!(s, "- **{}**: {}", l.licence, l.what);
        }
        let attributions: BTreeSet<&str> = FILES
            .iter()
            .filter(|f| {
                f.licence.starts_with("CC-BY") && licences.iter().any(|l| l.licence == f.licence)
            })
            .map(|f| f.source)
            .collect();
        for a in attributions {
            let _ = writeln!(s, "\nAttribution: {a}.");
        }
        *s += "\n`stereogen assets list` names every file of the content pack with its source and licence.\n";
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn licences_map_to_the_hub_and_sizes_to_categories() {
        assert_eq!(hub_licence("CC-BY-4.0"), Some("cc-by-4.0"));
        assert_eq!(hub_licence("by-sa"), Some("cc-by-sa-4.0"));
        assert_eq!(hub_licence("public-domain"), None);
        assert_eq!(size_category(999), "n<1K");
        assert_eq!(size_category(200_000), "100K<n<1M");
    }

    #[test]
    fn the_default_preset_lists_the_pack_licences_and_exclusions_apply() {
        let mut recipe = Recipe::preset("crestereo").unwrap();
        let all: BTreeSet<String> = licences_of(&recipe)
            .into_iter()
            .map(|l| l.licence)
            .collect();
        for l in ["CC0-1.0", "CC-BY-4.0", "MIT", "Apache-2.0", "public-domain"] {
            assert!(all.contains(l), "{l} missing from {all:?}");
        }
        recipe.sources.exclude_licences = vec!["cc-by-4.0".into()];
        let kept: BTreeSet<String> = licences_of(&recipe)
            .into_iter()
            .map(|l| l.licence)
            .collect();
        assert!(!kept.contains("CC-BY-4.0"), "{kept:?}");
        recipe.sources.builtin_pack = false;
        assert!(licences_of(&recipe).is_empty());
    }

    #[test]
    fn environments_list_blenders_hdr_maps() {
        let hdr = |recipe: &Recipe| {
            licences_of(recipe)
                .into_iter()
                .any(|l| l.licence == "CC0-1.0" && l.what.contains("HDR environment maps"))
        };
        let mut recipe = Recipe::preset("wmgstereo").unwrap();
        assert!(hdr(&recipe));
        recipe.sources.builtin_pack = false;
        assert!(hdr(&recipe), "without the pack the maps are still used");
        assert!(!hdr(&Recipe::preset("crestereo").unwrap()));
    }
}
