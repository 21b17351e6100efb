//! `stereogen assets fetch objaverse`: real objects for users without ShapeNet. Reads the
//! Objaverse 1.0 index, picks objects whose licence (and optionally category) the user allows,
//! and downloads their GLBs in parallel into a mesh folder that `--meshes` reads. Each object
//! gets `<uid>.glb` and `<uid>.json` (its licence, author, source and SHA-256). Interrupted
//! downloads resume from their `.part` file; finished objects are not fetched again.

pub mod download;
pub mod index;
pub mod licence;

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use anyhow::{Context, bail};

pub use index::ObjectRecord;
use index::{Annotation, gunzip_json, parse_object_paths};

/// Where Objaverse 1.0 is published.
pub const DEFAULT_BASE_URL: &str = "https://huggingface.co/datasets/allenai/objaverse/resolve/main";

#[derive(Debug, Clone)]
pub struct FetchOptions {
    /// The dataset root: `<base>/object-paths.json.gz`, `<base>/metadata/<shard>.json.gz`, `<base>/<path>`.
    pub base_url: String,
    pub count: usize,
    /// Licences accepted, as the user wrote them (`cc0`, `cc-by`, `by-sa`, ...).
    pub licences: Vec<String>,
    /// Accept NC/ND licences the user lists.
    pub allow_restricted: bool,
    /// Keep objects with one of these Sketchfab categories or tags (empty: any).
    pub categories: Vec<String>,
    pub out: PathBuf,
    /// Parallel downloads.
    pub jobs: usize,
    /// Further attempts per file after a lost connection or a server error.
    pub retries: u32,
    pub timeout: Duration,
}

impl FetchOptions {
    pub fn new(out: impl Into<PathBuf>, count: usize) -> Self {
        Self {
            base_url: DEFAULT_BASE_URL.into(),
            count,
            licences: vec!["cc0".into(), "by".into()],
            allow_restricted: false,
            categories: Vec::new(),
            out: out.into(),
            jobs: 4,
            retries: 3,
            timeout: Duration::from_secs(60),
        }
    }
}

/// What [`fetch`] reports as it goes (from the download threads).
#[derive(Debug, Clone, Copy)]
pub enum FetchEvent<'a> {
    /// The objects are chosen: `total` to have, `present` of them already there.
    Selected {
        total: usize,
        present: usize,
    },
    Bytes(u64),
    Done {
        uid: &'a str,
    },
    Failed {
        uid: &'a str,
        error: &'a str,
    },
}

#[derive(Debug, Clone, Default)]
pub struct FetchSummary {
    pub selected: usize,
    pub downloaded: usize,
    /// Objects of the selection that were already fetched and verified.
    pub present: usize,
    /// Objects passed over for their licence.
    pub skipped_licence: usize,
    /// Objects that did not download or verify (nothing of them is left in the folder).
    pub failed: Vec<(String, String)>,
}

fn read_url(agent: &ureq::Agent, url: &str) -> anyhow::Result<Vec<u8>> {
    let mut buf = Vec::new();
    let resp = agent
        .get(url)
        .call()
        .map_err(|e| anyhow::anyhow!("cannot fetch {url}: {e}"))?;
    std::io::Read::read_to_end(&mut resp.into_reader(), &mut buf)
        .with_context(|| format!("cannot fetch {url}"))?;
    Ok(buf)
}

/// An index file, kept under `<out>/.objaverse/` so a re-run reads it from disk.
fn index_file(agent: &ureq::Agent, opts: &FetchOptions, rel: &str) -> anyhow::Result<Vec<u8>> {
    let cache = opts.out.join(".objaverse").join(rel);
    if let Ok(bytes) = std::fs::read(&cache) {
        return Ok(bytes);
    }
    let bytes = read_url(
        agent,
        &format!("{}/{rel}", opts.base_url.trim_end_matches('/')),
    )?;
    if let Some(dir) = cache.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    stereo_io::write_bytes_atomically(&cache, &bytes)?;
    Ok(bytes)
}

/// A GLB: the `glTF` magic, version 2, and a declared length equal to the file's.
pub fn check_glb(path: &Path) -> Result<(), String> {
    let mut head = [0u8; 12];
    let len = std::fs::metadata(path).map_err(|e| e.to_string())?.len();
    std::io::Read::read_exact(
        &mut std::fs::File::open(path).map_err(|e| e.to_string())?,
        &mut head,
    )
    .map_err(|_| format!("not a GLB: {len} bytes"))?;
    if &head[..4] != b"glTF" {
        return Err("not a GLB: no glTF magic".into());
    }
    let version = u32::from_le_bytes(head[4..8].try_into().expect("4 bytes"));
    let declared = u64::from(u32::from_le_bytes(head[8..12].try_into().expect("4 bytes")));
    if version != 2 {
        return Err(format!("not a GLB 2.0 file: version {version}"));
    }
    if declared != len {
        return Err(format!(
            "truncated or padded GLB: header says {declared} bytes, the file has {len}"
        ));
    }
    Ok(())
}

/// An object already fetched: its GLB matches the checksum its record states.
fn is_present(out: &Path, uid: &str) -> bool {
    let Ok(text) = std::fs::read_to_string(out.join(format!("{uid}.json"))) else {
        return false;
    };
    let Ok(record) = serde_json::from_str::<ObjectRecord>(&text) else {
        return false;
    };
    stereo_io::digest::sha256_file(&out.join(format!("{uid}.glb")))
        .is_ok_and(|sha| sha == record.sha256)
}

/// Picks the first `count` objects, in shard and uid order, whose licence and category pass.
fn select(
    agent: &ureq::Agent,
    opts: &FetchOptions,
    accepted: &[String],
    summary: &mut FetchSummary,
) -> anyhow::Result<Vec<(String, String, Annotation)>> {
    let paths = parse_object_paths(&index_file(agent, opts, "object-paths.json.gz")?)?;
    let mut by_shard: BTreeMap<&str, Vec<(&str, &str)>> = BTreeMap::new();
    for (uid, (shard, path)) in &paths {
        by_shard.entry(shard).or_default().push((uid, path));
    }
    let mut chosen = Vec::new();
    for (shard, objects) in by_shard {
        if chosen.len() >= opts.count {
            break;
        }
        let rel = format!("metadata/{shard}.json.gz");
        let annotations: BTreeMap<String, Annotation> =
            gunzip_json(&index_file(agent, opts, &rel)?, &rel)?;
        for (uid, path) in objects {
            if chosen.len() >= opts.count {
                break;
            }
            let Some(a) = annotations.get(uid) else {
                continue;
            };
            let slug = licence::normalise(a.license.as_deref().unwrap_or(""));
            if !accepted.contains(&slug) {
                summary.skipped_licence += 1;
                continue;
            }
            if a.in_categories(&opts.categories) {
                chosen.push((uid.to_string(), path.to_string(), a.clone()));
            }
        }
    }
    Ok(chosen)
}

/// Downloads one object and writes its record; the record is written last, so an object is
/// either complete or absent.
fn fetch_one(
    agent: &ureq::Agent,
    opts: &FetchOptions,
    uid: &str,
    path: &str,
    a: &Annotation,
    progress: &(dyn Fn(FetchEvent<'_>) + Sync),
) -> Result<(), String> {
    let url = format!("{}/{path}", opts.base_url.trim_end_matches('/'));
    let glb = opts.out.join(format!("{uid}.glb"));
    let (sha256, bytes) = download::download(
        agent,
        &url,
        &glb,
        opts.retries,
        &|n| progress(FetchEvent::Bytes(n)),
        &check_glb,
    )?;
    let record = ObjectRecord {
        uid: uid.to_string(),
        name: a.name.clone(),
        licence: licence::normalise(a.license.as_deref().unwrap_or("")),
        author: a
            .user
            .as_ref()
            .map(|u| u.username.clone())
            .filter(|u| !u.is_empty()),
        source: a.viewer_url.clone(),
        url,
        sha256,
        bytes,
    };
    let json = serde_json::to_string_pretty(&record).expect("a record serialises");
    stereo_io::write_bytes_atomically(&opts.out.join(format!("{uid}.json")), json.as_bytes())
        .map_err(|e| e.to_string())
}

/// Fetches `opts.count` objects into `opts.out`. Objects that fail are reported in the summary
/// (and leave nothing behind); an unreachable or malformed index is an error.
pub fn fetch(
    opts: &FetchOptions,
    progress: &(dyn Fn(FetchEvent<'_>) + Sync),
) -> anyhow::Result<FetchSummary> {
    if opts.count == 0 {
        bail!("--count must be at least 1");
    }
    let accepted = licence::accepted(&opts.licences, opts.allow_restricted)?;
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("cannot create {}", opts.out.display()))?;
    let agent = download::agent(opts.timeout);
    let mut summary = FetchSummary::default();
    let chosen = select(&agent, opts, &accepted, &mut summary)?;
    summary.selected = chosen.len();
    let (present, todo): (Vec<_>, Vec<_>) = chosen
        .into_iter()
        .partition(|(uid, _, _)| is_present(&opts.out, uid));
    summary.present = present.len();
    progress(FetchEvent::Selected {
        total: summary.selected,
        present: summary.present,
    });
    let queue = Mutex::new(todo.into_iter().collect::<VecDeque<_>>());
    let results = Mutex::new((0usize, Vec::new()));
    std::thread::scope(|s| {
        for _ in 0..opts.jobs.max(1) {
            s.spawn(|| {
                while let Some((uid, path, a)) = queue.lock().unwrap().pop_front() {
                    match fetch_one(&agent, opts, &uid, &path, &a, progress) {
                        Ok(()) => {
                            results.lock().unwrap().0 += 1;
                            progress(FetchEvent::Done { uid: &uid });
                        }
                        Err(error) => {
                            progress(FetchEvent::Failed {
                                uid: &uid,
                                error: &error,
                            });
                            results.lock().unwrap().1.push((uid, error));
                        }
                    }
                }
            });
        }
    });
    let (downloaded, mut failed) = results.into_inner().unwrap();
    failed.sort();
    summary.downloaded = downloaded;
    summary.failed = failed;
    Ok(summary)
}
