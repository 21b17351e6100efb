//! The README and the guide (docs/guide/) hold up:
//! - every command block is run as written: the shell and Python blocks of the README's tour and
//!   of each guide page, in page order, in one working folder laid out like the repository (its
//!   top-level entries linked in), with the binaries under test first on the PATH and a fresh
//!   venv (PyTorch, `datasets`, `webdataset` beside it) as `python` and `pip`;
//! - every command block carries a `<!-- run: NAME -->` marker that names who runs it, and every
//!   fenced block names its language;
//! - the command reference (docs/guide/reference/) is the binaries' `--help`, regenerated and
//!   compared (`STEREOGEN_BLESS_DOCS=1` rewrites it);
//! - every relative link and anchor of the README, the changelog, the crates' READMEs and docs/
//!   resolves;
//! - the README's test command is `.ci/run`'s.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;
use test_support::{output_text, python_envs};

use python_envs::{base_venvs, fresh_venv, python_home, repo_root, target_dir};

/// The pages whose command blocks `guide_commands_run_as_written` runs, in order, and the marker
/// name of their blocks.
const PAGES: &[(&str, &str)] = &[
    ("README.md", "tour"),
    ("docs/guide/make-a-dataset.md", "make-a-dataset"),
    ("docs/guide/farm.md", "farm"),
    ("docs/guide/validate.md", "validate"),
    ("docs/guide/export-and-share.md", "export"),
    ("docs/guide/python.md", "python"),
    ("docs/guide/train.md", "train"),
    ("docs/guide/train-distributed.md", "train-distributed"),
    ("docs/guide/evaluate.md", "evaluate"),
    ("docs/guide/deploy.md", "deploy"),
];

/// Blocks run elsewhere: marker name, and the test file that finds the marker.
const RUN_ELSEWHERE: &[(&str, &str)] = &[(
    "onnx-snippet",
    "crates/crestereo-train/tests/integration/export_onnx.rs",
)];

const COMMAND_LANGUAGES: &[&str] = &["sh", "bash", "shell", "console", "python", "py"];

/// A fenced block of a Markdown file.
struct Block {
    line: usize,
    lang: String,
    code: String,
    /// The marker's name on the last non-blank line before the fence, if any.
    run: Option<String>,
}

fn blocks(text: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let l = lines[i];
        if let Some(lang) = l.strip_prefix("```") {
            let start = i;
            let mut code = String::new();
            i += 1;
            while i < lines.len() && !lines[i].starts_with("```") {
                code += lines[i];
                code.push('\n');
                i += 1;
            }
            let run = lines[..start]
                .iter()
                .rev()
                .find(|l| !l.trim().is_empty())
                .and_then(|l| l.trim().strip_prefix("<!-- run: "))
                .and_then(|l| l.strip_suffix("-->"))
                .map(|m| m.split_whitespace().next().unwrap_or("").to_string());
            out.push(Block {
                line: start + 1,
                lang: lang.trim().to_string(),
                code,
                run,
            });
        }
        i += 1;
    }
    out
}

fn read(rel: &str) -> String {
    std::fs::read_to_string(repo_root().join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

/// README.md and every page of the guide but the generated reference.
fn guide_pages() -> Vec<String> {
    let mut pages = vec!["README.md".to_string()];
    let dir = repo_root().join("docs/guide");
    let mut found: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .map(|p| format!("docs/guide/{}", p.file_name().unwrap().to_string_lossy()))
        .collect();
    found.sort();
    pages.extend(found);
    pages
}

#[test]
fn every_command_block_says_who_runs_it() {
    let known: BTreeMap<&str, &str> = PAGES.iter().map(|&(p, n)| (n, p)).collect();
    let mut problems = Vec::new();
    let mut used = BTreeSet::new();
    for page in guide_pages() {
        for b in blocks(&read(&page)) {
            let at = format!("{page}:{}", b.line);
            if b.lang.is_empty() {
                problems.push(format!(
                    "{at}: a block without a language (`text` for output)"
                ));
                continue;
            }
            if !COMMAND_LANGUAGES.contains(&b.lang.as_str()) {
                continue;
            }
            let Some(name) = b.run else {
                problems.push(format!(
                    "{at}: a {} block without a `<!-- run: NAME -->` marker",
                    b.lang
                ));
                continue;
            };
            used.insert(name.clone());
            if name == "setup" {
                continue; // checked by the_readme_test_command_is_ci_run
            }
            if let Some(&(_, file)) = RUN_ELSEWHERE.iter().find(|(n, _)| *n == name) {
                let marker = format!("<!-- run: {name} -->");
                if !read(file).contains(&marker) {
                    problems.push(format!("{at}: {file} does not look for {marker}"));
                }
                continue;
            }
            match known.get(name.as_str()) {
                Some(p) if *p == page => {}
                Some(p) => problems.push(format!("{at}: marker {name} belongs to {p}")),
                None => problems.push(format!("{at}: no test runs blocks marked {name}")),
            }
        }
    }
    for (page, name) in PAGES {
        if !used.contains(*name) {
            problems.push(format!(
                "{page}: no block marked {name}, which the runner expects"
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_readme_test_command_is_ci_run() {
    let readme = read("README.md");
    let setup = blocks(&readme)
        .into_iter()
        .find(|b| b.run.as_deref() == Some("setup"))
        .expect("the set-up block");
    // Command 1 runs the demo (`cargo run ... generate`); command 2 is the test command.
    let commands: Vec<&str> = setup
        .code
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .collect();
    assert_eq!(commands.len(), 2, "two commands: {commands:?}");
    let ci = read(".ci/run");
    let last = ci
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .unwrap();
    assert_eq!(
        last.strip_prefix("exec "),
        Some(commands[1]),
        ".ci/run: {last}"
    );
    // And the script it names is there and runs every phase.
    let script = read(commands[1]);
    for phase in [
        "cargo fmt --all --check",
        "cargo clippy --workspace --all-targets --release",
        "cargo test --workspace --release --no-run",
        "cargo test --workspace --release",
        "fuzz/run 30",
    ] {
        assert!(script.contains(phase), "{} lacks {phase}", commands[1]);
    }
}

/// GitHub's anchor of a heading: lower case, letters, digits, `-`, `_` and spaces kept, spaces
/// made `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The text outside fenced blocks and inline code.
fn prose(text: &str) -> String {
    let mut out = String::new();
    let mut fenced = false;
    for l in text.lines() {
        if l.starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if !fenced {
            let mut in_code = false;
            for c in l.chars() {
                if c == '`' {
                    in_code = !in_code;
                } else if !in_code {
                    out.push(c);
                }
            }
            out.push('\n');
        }
    }
    out
}

fn anchors(text: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    let mut fenced = false;
    for l in text.lines() {
        if l.starts_with("```") {
            fenced = !fenced;
        }
        if fenced {
            continue;
        }
        if let Some(h) = l.strip_prefix('#') {
            let base = slug(h.trim_start_matches('#').replace('`', "").as_str());
            let n = seen.entry(base.clone()).or_default();
            out.insert(if *n == 0 {
                base.clone()
            } else {
                format!("{base}-{n}")
            });
            *n += 1;
        }
    }
    out
}

/// `[text](target)` and `![alt](target)` targets in prose.
fn links(text: &str) -> Vec<String> {
    let p = prose(text);
    let mut out = Vec::new();
    let mut rest = p.as_str();
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                out.push(after[..j].trim().to_string());
                rest = &after[j..];
            }
            None => break,
        }
    }
    out
}

fn markdown_files() -> Vec<PathBuf> {
    let root = repo_root();
    let mut files = vec![root.join("README.md"), root.join("CHANGELOG.md")];
    for dir in ["crates", "docs"] {
        let mut stack = vec![root.join(dir)];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                if p.is_dir() && name != "target" && !name.starts_with('.') {
                    stack.push(p);
                } else if name.ends_with(".md") {
                    files.push(p);
                }
            }
        }
    }
    files.sort();
    files
}

#[test]
fn relative_links_and_anchors_resolve() {
    let root = repo_root().canonicalize().unwrap();
    let mut problems = Vec::new();
    let mut checked = 0;
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        let rel = file
            .strip_prefix(repo_root())
            .unwrap()
            .display()
            .to_string();
        for link in links(&text) {
            if link.contains("://") || link.starts_with("mailto:") || link.is_empty() {
                continue;
            }
            let (path, anchor) = match link.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (link.as_str(), None),
            };
            let target = if path.is_empty() {
                file.clone()
            } else {
                file.parent().unwrap().join(path)
            };
            let Ok(target) = target.canonicalize() else {
                problems.push(format!("{rel}: {link}: no such file"));
                continue;
            };
            if !target.starts_with(&root) {
                continue; // outside the repository (../shared/): not ours to check
            }
            checked += 1;
            if let Some(a) = anchor {
                let is_md = target.extension().is_some_and(|x| x == "md");
                let known =
                    is_md && anchors(&std::fs::read_to_string(&target).unwrap()).contains(a);
                if !known {
                    problems.push(format!("{rel}: {link}: no heading with anchor #{a}"));
                }
            }
        }
    }
    println!("{checked} relative links checked");
    assert!(
        checked > 50,
        "only {checked} links found: is the parser broken?"
    );
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn anchors_follow_github() {
    assert_eq!(
        slug(" What a run will cost: stereogen estimate"),
        "what-a-run-will-cost-stereogen-estimate"
    );
    assert_eq!(
        slug("CREStereo against PyTorch (CPU)"),
        "crestereo-against-pytorch-cpu"
    );
    let a = anchors("# A\n## B b\n```sh\n# not a heading\n```\n## B b\n");
    assert_eq!(a, ["a", "b-b", "b-b-1"].map(String::from).into());
    assert_eq!(
        links("[x](a.md#b) `[y](c.md)` ![i](d.png)"),
        ["a.md#b", "d.png"]
    );
}

// ---------------------------------------------------------------------------------------------
// The command reference, generated from --help.

/// The binaries under test (`cargo test --workspace` builds them next to the test).
fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let bin = exe.parent().unwrap().parent().unwrap().join(name);
    assert!(
        bin.is_file(),
        "{} missing: run through `cargo test --workspace`",
        bin.display()
    );
    bin
}

fn help(bin_path: &Path, args: &[&str]) -> String {
    let mut c = Command::new(bin_path);
    c.args(args).arg("--help").env("COLUMNS", "100");
    for (k, _) in std::env::vars() {
        if ["STEREOGEN_", "CRESTEREO_", "CUBECL_", "RAYON_"]
            .iter()
            .any(|p| k.starts_with(p))
        {
            c.env_remove(k);
        }
    }
    let out = c.output().unwrap();
    assert!(
        out.status.success(),
        "{args:?} --help: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let home = std::env::var("HOME").unwrap_or_default();
    let text = if home.len() > 1 {
        text.replace(&home, "~")
    } else {
        text
    };
    text.lines()
        .map(str::trim_end)
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// The subcommands a help text lists (its `Commands:` section), `help` left out.
fn subcommands(help: &str) -> Vec<(String, String)> {
    help.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| {
            let l = l.trim();
            let (name, what) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
            (name != "help").then(|| (name.to_string(), what.trim().to_string()))
        })
        .collect()
}

/// The reference pages: file name → content.
fn reference_pages() -> BTreeMap<String, String> {
    let note = "<!-- generated from `--help` by tests/integration/guide.rs: run `STEREOGEN_BLESS_DOCS=1 cargo test --release -p stereogen-e2e --test integration guide::reference` after `cargo build --release` to rewrite -->";
    let mut pages = BTreeMap::new();
    let mut index = format!(
        "# Command reference\n\n{note}\n\nEvery page is the command's `--help`, as the binary prints it.\n"
    );
    for name in ["stereogen", "crestereo"] {
        let b = bin(name);
        let top = help(&b, &[]);
        let _ = std::fmt::Write::write_fmt(&mut index, format_args!("\n## `{name}`\n\n"));
        pages.insert(
            format!("{name}.md"),
            format!("# {name}\n\n{note}\n\n```text\n{top}```\n"),
        );
        index += &format!("- [`{name}`]({name}.md): the overview\n");
        for (sub, what) in subcommands(&top) {
            let h = help(&b, &[&sub]);
            let mut page = format!("# {name} {sub}\n\n{note}\n\n```text\n{h}```\n");
            for (nested, _) in subcommands(&h) {
                let nh = help(&b, &[&sub, &nested]);
                page += &format!("\n## {name} {sub} {nested}\n\n```text\n{nh}```\n");
            }
            index += &format!("- [`{name} {sub}`]({name}-{sub}.md): {what}\n");
            pages.insert(format!("{name}-{sub}.md"), page);
        }
    }
    pages.insert("README.md".into(), index);
    pages
}

#[test]
fn reference_pages_are_the_help() {
    let dir = repo_root().join("docs/guide/reference");
    let pages = reference_pages();
    if std::env::var_os("STEREOGEN_BLESS_DOCS").is_some() {
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, text) in &pages {
            std::fs::write(dir.join(name), text).unwrap();
        }
    }
    let mut problems = Vec::new();
    for (name, text) in &pages {
        match std::fs::read_to_string(dir.join(name)) {
            Ok(t) if t == *text => {}
            Ok(_) => problems.push(format!("{name}: differs from the help")),
            Err(_) => problems.push(format!("{name}: missing")),
        }
    }
    for e in std::fs::read_dir(&dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        if !pages.contains_key(&name) {
            problems.push(format!("{name}: no such command any more"));
        }
    }
    assert!(
        problems.is_empty(),
        "docs/guide/reference/ drifted from --help (rewrite it with STEREOGEN_BLESS_DOCS=1):\n{}",
        problems.join("\n")
    );
}

// ---------------------------------------------------------------------------------------------
// The commands, run as written.

/// A working folder that looks like the repository's root: its top-level entries linked in.
fn repo_like_workdir(dir: &Path) {
    for e in std::fs::read_dir(repo_root()).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_os_string();
        if name == ".git" || name == "target" {
            continue;
        }
        std::os::unix::fs::symlink(&p, dir.join(&name)).unwrap();
    }
}

#[test]
fn guide_commands_run_as_written() {
    let work = tempfile::tempdir().unwrap();
    repo_like_workdir(work.path());
    // The binaries under test first on the PATH.
    let shims = tempfile::tempdir().unwrap();
    for name in ["stereogen", "crestereo"] {
        std::os::unix::fs::symlink(bin(name), shims.path().join(name)).unwrap();
    }
    let (torch, hub) = base_venvs();
    let venv = fresh_venv(&python_home().join("guide-venv"), &[&hub, &torch]);
    let path = format!(
        "{}:{}:{}",
        shims.path().display(),
        venv.join("bin").display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let run = |what: &str, cmd: &mut Command| {
        let t = Instant::now();
        let out = cmd
            .current_dir(work.path())
            .env("PATH", &path)
            .env("VIRTUAL_ENV", &venv)
            // The cargo folder of the tests' other maturin builds: the README's wheel block
            // then compiles only what its interpreter changes (pyo3 and the module).
            .env("CARGO_TARGET_DIR", target_dir().join("python-ext"))
            .env("HF_HUB_OFFLINE", "1")
            .env("HF_DATASETS_OFFLINE", "1")
            // tests/run's test runner sets it for libtest; the wheel block's cargo must not see it.
            .env_remove("RUSTC_BOOTSTRAP")
            .env_remove("STEREOGEN_FAULT")
            .env_remove("STEREOGEN_SHARD")
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap();
        let said = output_text(&out);
        assert!(
            out.status.success(),
            "{what} failed ({}):\n{said}",
            out.status
        );
        println!("{what}: {:.1} s", t.elapsed().as_secs_f64());
        let lines: Vec<&str> = said.lines().collect();
        for l in &lines[lines.len().saturating_sub(12)..] {
            println!("    {l}");
        }
        said
    };
    for (page, name) in PAGES {
        for b in blocks(&read(page)) {
            if b.run.as_deref() != Some(*name) {
                continue;
            }
            let what = format!("{page}:{} ({})", b.line, b.lang);
            if b.lang.starts_with("py") {
                let file = work.path().join(format!("block-{}.py", b.line));
                std::fs::write(&file, &b.code).unwrap();
                run(&what, Command::new(venv.join("bin/python")).arg(&file));
            } else {
                // A block that builds the wheel takes the cargo folder's turn.
                let _turn = b
                    .code
                    .contains("maturin build")
                    .then(test_support::turns::python_ext);
                run(
                    &what,
                    Command::new("bash").args(["-euo", "pipefail", "-c", &b.code]),
                );
            }
        }
    }
    // What the blocks made: a card with the content pack's licences, the reports, the models.
    let card = std::fs::read_to_string(work.path().join("tour-shards/README.md")).unwrap();
    for needle in [
        "- cc0-1.0",
        "- cc-by-4.0",
        "- mit",
        "- apache-2.0",
        "task_categories:",
    ] {
        assert!(
            card.contains(needle),
            "the tour's card lacks {needle:?}:\n{card}"
        );
    }
    for made in [
        "tour/report.html",
        "tour-run/eval.json",
        "eval-disturbed.disturb.csv",
        "eval-disturbed.disturb.png",
        "disparity.exr",
        "disparity.png",
        "farm/manifest.jsonl",
        "farm-shards/README.md",
        "crestereo.onnx",
        "crestereo.pth",
        "mixed-run/loss.png",
        "job/train.sbatch",
    ] {
        assert!(work.path().join(made).is_file(), "{made} was not made");
    }
    // Two replicas in one process and two ranks over the loopback train on the same samples.
    let losses = |run: &str| {
        crestereo_train::parallel::compare::logged_losses(&work.path().join(run))
            .unwrap_or_else(|e| panic!("{run}: {e:#}"))
    };
    let (replicas, ranks) = (losses("two-replicas"), losses("two-ranks"));
    assert_eq!(replicas.len(), ranks.len(), "{replicas:?} vs {ranks:?}");
    for ((sa, a), (sb, b)) in replicas.iter().zip(&ranks) {
        assert!(
            sa == sb && (a - b).abs() <= 1e-5 * a.abs().max(1e-3),
            "two replicas {replicas:?} vs two ranks {ranks:?}"
        );
    }
}
