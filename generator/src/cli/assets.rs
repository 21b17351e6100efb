//! `stereogen assets`: what the built-in content pack holds (`list`, `info`), and fetching
//! Objaverse objects into a mesh folder (`fetch objaverse`).

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use anyhow::bail;
use clap::Subcommand;
use indicatif::{ProgressBar, ProgressStyle};
use stereogen::assets::objaverse::{DEFAULT_BASE_URL, FetchEvent, FetchOptions, fetch};
use stereogen::assets::pack::{PackEntry, PackIndex, installed_index};
use stereogen::assets::stereogen_home;

#[derive(Debug, Subcommand)]
pub enum AssetsCommand {
    /// Every file of the installed content pack: kind, licence, package, size and path.
    List {
        /// Leave out files under these licences (as listed, e.g. CC-BY-4.0), as a recipe's
        /// `sources.exclude_licences` would.
        #[arg(long, value_name = "LICENCE", value_delimiter = ',')]
        exclude_licences: Vec<String>,
    },
    /// Everything known about one pack file: source, licence, checksum, size.
    Info {
        /// The file's path in the pack, or its file name (`brick.png`).
        file: String,
    },
    /// Download real objects from an online source into a mesh folder for `--meshes`.
    Fetch {
        #[command(subcommand)]
        source: FetchSource,
    },
}

#[derive(Debug, Subcommand)]
pub enum FetchSource {
    /// Objaverse 1.0 (Sketchfab objects, per-object Creative Commons licences) as GLB files, each
    /// with `<uid>.json` stating its licence, author and SHA-256. Re-running resumes.
    Objaverse {
        /// Objects to have in DIR.
        #[arg(long, value_name = "N")]
        count: usize,
        /// Accepted licences (cc0, cc-by, cc-by-sa, ...); NC/ND ones need --allow-nc-nd.
        #[arg(
            long,
            value_name = "LICENCES",
            value_delimiter = ',',
            default_value = "cc0,cc-by"
        )]
        license: Vec<String>,
        /// Let --license name licences that forbid commercial use or derivatives.
        #[arg(long)]
        allow_nc_nd: bool,
        /// Keep objects with one of these Sketchfab categories or tags (e.g. furniture-home).
        #[arg(long, value_name = "NAMES", value_delimiter = ',')]
        categories: Vec<String>,
        /// The mesh folder to fill (created if missing).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Parallel downloads.
        #[arg(long, value_name = "K", default_value_t = 4)]
        jobs: usize,
        /// The dataset's root URL (a mirror).
        #[arg(long, value_name = "URL", env = "STEREOGEN_OBJAVERSE_URL", default_value = DEFAULT_BASE_URL)]
        base_url: String,
        /// Hide the progress bar.
        #[arg(long)]
        no_progress: bool,
    },
}

fn mib(bytes: u64) -> String {
    format!("{:.2} MiB", bytes as f64 / (1024.0 * 1024.0))
}

fn print_list(index: &PackIndex) {
    println!("{} ({})", index.name, index.root.display());
    for e in &index.entries {
        let size = e.size.map(|[w, h]| format!("{w}x{h}")).unwrap_or_default();
        println!(
            "{:<5} {:<13} {:<22} {:>10} {:>9}  {}",
            format!("{:?}", e.kind).to_lowercase(),
            e.licence,
            format!("{}=={}", e.package, e.version),
            mib(e.bytes),
            size,
            e.file
        );
    }
    for ((kind, licence), n) in index.licence_counts() {
        println!(
            "total: {n} {}(s) under {licence}",
            format!("{kind:?}").to_lowercase()
        );
    }
    println!(
        "total: {} file(s), {}; fingerprint {}",
        index.entries.len(),
        mib(index.entries.iter().map(|e| e.bytes).sum()),
        index.fingerprint
    );
    for f in &index.excluded {
        println!("excluded by licence: {f}");
    }
    for s in &index.skipped {
        println!("skipped: {}: {}", s.path.display(), s.reason);
    }
}

fn print_info(e: &PackEntry) {
    println!("file:     {}", e.file);
    println!("path:     {}", e.path.display());
    println!("kind:     {}", format!("{:?}", e.kind).to_lowercase());
    println!("package:  {}=={}", e.package, e.version);
    println!("licence:  {}", e.licence);
    println!("source:   {}", e.source);
    println!("sha256:   {}", e.sha256);
    println!("bytes:    {}", e.bytes);
    if let Some([w, h]) = e.size {
        println!("pixels:   {w}x{h}");
    }
}

fn fetch_bar(show: bool) -> ProgressBar {
    let bar = if show {
        ProgressBar::new(0)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} objects · {msg}",
        )
        .expect("static template"),
    );
    bar
}

pub fn run(command: AssetsCommand) -> anyhow::Result<()> {
    match command {
        AssetsCommand::List { exclude_licences } => {
            print_list(&installed_index(&stereogen_home(), &exclude_licences)?)
        }
        AssetsCommand::Info { file } => {
            let index = installed_index(&stereogen_home(), &[])?;
            let found = index
                .entries
                .iter()
                .find(|e| e.file == file || e.file.rsplit('/').next() == Some(file.as_str()));
            let Some(entry) = found else {
                if let Some(s) = index.skipped.iter().find(|s| s.path.ends_with(&file)) {
                    bail!("{file}: in the pack but not usable: {}", s.reason);
                }
                bail!(
                    "{file}: no such file in the content pack (`stereogen assets list` shows them)"
                );
            };
            print_info(entry);
        }
        AssetsCommand::Fetch {
            source:
                FetchSource::Objaverse {
                    count,
                    license,
                    allow_nc_nd,
                    categories,
                    out,
                    jobs,
                    base_url,
                    no_progress,
                },
        } => {
            let mut opts = FetchOptions::new(&out, count);
            opts.licences = license;
            opts.allow_restricted = allow_nc_nd;
            opts.categories = categories;
            opts.jobs = jobs;
            opts.base_url = base_url;
            let bar = fetch_bar(!no_progress);
            let bytes = AtomicU64::new(0);
            let s = fetch(&opts, &|event| match event {
                FetchEvent::Selected { total, present } => {
                    bar.set_length(total as u64);
                    bar.set_position(present as u64);
                    bar.enable_steady_tick(Duration::from_millis(250));
                }
                FetchEvent::Bytes(n) => {
                    bar.set_message(mib(bytes.fetch_add(n, Ordering::Relaxed) + n))
                }
                FetchEvent::Done { .. } => bar.inc(1),
                FetchEvent::Failed { uid, error } => {
                    bar.println(format!("{uid}: {error}"));
                    bar.inc(1);
                }
            });
            bar.finish_and_clear();
            let s = s?;
            eprintln!(
                "stereogen: {} object(s) downloaded, {} already there, {} failed, {} passed over for their licence -> {}",
                s.downloaded,
                s.present,
                s.failed.len(),
                s.skipped_licence,
                out.display()
            );
            if s.selected < count {
                eprintln!(
                    "stereogen: only {} object(s) of the index match the licences and categories asked for",
                    s.selected
                );
            }
            if !s.failed.is_empty() {
                bail!(
                    "{} object(s) failed; re-run the same command to retry them",
                    s.failed.len()
                );
            }
        }
    }
    Ok(())
}
