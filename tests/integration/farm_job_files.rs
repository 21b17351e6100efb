//! The Open Job Description template and the Kubernetes Jobs that `stereogen farm` writes,
//! checked by their own tools and run locally:
//! - `openjd check` accepts the template and `openjd run` renders 2 shards, merges and checks;
//! - `kubernetes-validate --strict` (the `batch/v1` schemas bundled in the PyPI package, no
//!   cluster needed) accepts both Jobs, and each render pod's command, run here with
//!   `JOB_COMPLETION_INDEX` and the pod's environment, renders its shard; the merge Job's
//!   commands then merge and check.
//! - with `--webdataset DIR` the merge step of all three (Slurm's too) passes the shard options
//!   on, and the OpenJD and Kubernetes merge steps run here write the shards.
//! - a task's default resources (8 cores, threads named on its command line, Slurm's
//!   `--signal=TERM@GRACE` and `--requeue`) are the same in all three; `--estimate` renders a
//!   few samples and sets every scheduler's time limit from them.
//!
//! The tools live in a virtual environment under `~/.cache/stereogen/farm-venv` (pinned
//! versions, installed with pip on first use). Where it cannot be made the tests print why and
//! pass, unless `CI` or `STEREOGEN_REQUIRE_FARM_TOOLS` is set.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;

use stereogen::dataset::Manifest;
use test_support::files::write_replaced;
use test_support::{
    farm_cmd, output_text as text, run_fails, stereogen_bin, stereogen_cmd, write_tiny_recipe,
};

/// The `--webdataset` options the farms here are written with (DIR is `OUT/wds`); a size in
/// bytes, as the job files spell it.
const SHARDS: [&str; 6] = [
    "--shard-size",
    "1024",
    "--shuffle-seed",
    "5",
    "--splits",
    "train=0.75,val=0.25",
];

const TOOLS: &[&str] = &["openjd-cli==0.8.0", "kubernetes-validate==1.37.0"];

/// The venv's `bin` directory, made on first use; `Err` says why not.
fn tools() -> Result<PathBuf, String> {
    static VENV: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    VENV.get_or_init(|| {
        let home = std::env::var_os("HOME").ok_or("HOME is not set")?;
        let venv = Path::new(&home).join(".cache/stereogen/farm-venv");
        let bin = venv.join("bin");
        let ready =
            |b: &Path| b.join("openjd").is_file() && b.join("kubernetes-validate").is_file();
        if !ready(&bin) {
            let o = Command::new("python3")
                .args(["-m", "venv"])
                .arg(&venv)
                .output()
                .map_err(|e| format!("python3 -m venv: {e}"))?;
            if !o.status.success() {
                return Err(format!(
                    "python3 -m venv failed: {}",
                    String::from_utf8_lossy(&o.stderr)
                ));
            }
            let o = Command::new(bin.join("pip"))
                .args(["install", "--quiet"])
                .args(TOOLS)
                .output()
                .map_err(|e| format!("pip: {e}"))?;
            if !o.status.success() {
                return Err(format!(
                    "pip install {} failed: {}",
                    TOOLS.join(" "),
                    String::from_utf8_lossy(&o.stderr).trim()
                ));
            }
        }
        Ok(bin)
    })
    .clone()
}

fn tools_or_skip(test: &str) -> Option<PathBuf> {
    match tools() {
        Ok(bin) => Some(bin),
        Err(why)
            if std::env::var_os("CI").is_some()
                || std::env::var_os("STEREOGEN_REQUIRE_FARM_TOOLS").is_some() =>
        {
            panic!("{test}: the farm tools are required here but: {why}")
        }
        Err(why) => {
            eprintln!("SKIPPED {test}: {why}");
            None
        }
    }
}

/// `farm SCHEDULER` of 4 samples in 2 tasks, its merge step writing shards into `OUT/wds`, with
/// a time limit (so the schedulers' own checks see its field).
fn farm(scheduler: &str, recipe: &Path, out: &Path) {
    let o = farm_cmd(scheduler, recipe, out, 4, 2)
        .args(["--seed", "4", "--time-limit", "2:00:00", "--webdataset"])
        .arg(out.join("wds"))
        .args(SHARDS)
        .output()
        .unwrap();
    assert!(o.status.success(), "farm {scheduler}: {}", text(&o));
}

/// The merged dataset, and its 4 samples as shards in `OUT/wds` (3 train, 1 val).
fn assert_merged(out: &Path) {
    let entries = Manifest::read(&out.join("manifest.jsonl")).expect("a merged manifest");
    assert_eq!(
        entries.iter().map(|e| e.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3]
    );
    assert!(out.join("merge.json").is_file());
    let wds = out.join("wds");
    for name in ["train-000002.tar", "val-000000.tar", "val.index.json"] {
        assert!(wds.join(name).is_file(), "the merge step wrote {name}");
    }
    let shards = stereo_io::open_dataset(&wds, None).expect("the shards read");
    assert_eq!(shards.len(), 4);
}

/// The merge step's arguments hold `--webdataset OUT/wds` and [`SHARDS`] in each scheduler's
/// file; relative and misplaced folders, and shard options without a folder, are refused.
#[test]
fn every_farm_passes_the_webdataset_options_to_its_merge_step() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    let wds = out.join("wds");
    let mut want = vec![
        "merge".to_string(),
        out.display().to_string(),
        "--webdataset".into(),
        wds.display().to_string(),
    ];
    want.extend(SHARDS.iter().map(|a| a.to_string()));
    let line = want.join(" ");
    for (scheduler, file) in [
        ("slurm", "merge.sbatch"),
        ("openjd", "openjd-template.yaml"),
        ("k8s", "k8s-merge.yaml"),
    ] {
        farm(scheduler, &recipe, &out);
        let text = std::fs::read_to_string(out.join("jobs").join(file)).unwrap();
        // Slurm: one shell command line; OpenJD and Kubernetes: one YAML list item an argument.
        let words: Vec<&str> = text
            .lines()
            .flat_map(|l| match l.trim().strip_prefix("- ") {
                Some(item) => vec![item],
                None => l.split_whitespace().collect(),
            })
            .map(|w| w.trim_matches(|c| c == '\'' || c == '"'))
            .collect();
        let found = words.windows(want.len()).any(|w| w == want.as_slice());
        assert!(found, "{scheduler}: no `{line}` in {file}:\n{text}");
    }
    for (scheduler, dir_arg, why) in [
        ("slurm", "wds".into(), "must be an absolute path"),
        (
            "k8s",
            dir.path().join("elsewhere"),
            "put the shards under it",
        ),
        ("openjd", out.join("shards/wds"), "a folder of their own"),
    ] {
        let said = run_fails(
            farm_cmd(scheduler, &recipe, &out, 4, 2)
                .arg("--webdataset")
                .arg(&dir_arg),
        );
        assert!(
            said.contains(why),
            "{scheduler} --webdataset {}: {said}",
            dir_arg.display()
        );
    }
    let said = run_fails(farm_cmd("slurm", &recipe, &out, 4, 2).args(SHARDS));
    assert!(said.contains("need --webdataset"), "{said}");
}

#[test]
fn openjd_checks_and_runs_the_template() {
    let Some(bin) = tools_or_skip("openjd_checks_and_runs_the_template") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    farm("openjd", &recipe, &out);
    let template = out.join("jobs/openjd-template.yaml");
    let o = Command::new(bin.join("openjd"))
        .arg("check")
        .arg(&template)
        .output()
        .unwrap();
    assert!(
        o.status.success() && text(&o).contains("passes validation checks"),
        "{}",
        text(&o)
    );
    // Check depends on Merge, which depends on Render's 2 tasks: all of them run.
    let o = Command::new(bin.join("openjd"))
        .arg("run")
        .arg(&template)
        .args(["--step", "Check", "--run-dependencies"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        o.status.success() && text(&o).contains("Session ended successfully"),
        "{}",
        text(&o)
    );
    assert!(
        text(&o).contains("Chunks run: 4"),
        "2 render tasks, merge and check: {}",
        text(&o)
    );
    assert_merged(&out);
}

/// A YAML file as JSON, through the venv's PyYAML (a dependency of kubernetes-validate).
fn yaml(bin: &Path, file: &Path) -> serde_json::Value {
    let o = Command::new(bin.join("python"))
        .args([
            "-c",
            "import json, sys, yaml; print(json.dumps(yaml.safe_load(open(sys.argv[1]))))",
        ])
        .arg(file)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// A container's command run here with its environment and `extra` variables.
fn run_container(container: &serde_json::Value, extra: &[(&str, &str)]) -> Output {
    let argv: Vec<&str> = container["command"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a.as_str().unwrap())
        .collect();
    let mut c = Command::new(argv[0]);
    c.args(&argv[1..])
        .stdin(Stdio::null())
        .env_remove("STEREOGEN_SHARD");
    for var in container["env"].as_array().into_iter().flatten() {
        c.env(
            var["name"].as_str().unwrap(),
            var["value"].as_str().unwrap(),
        );
    }
    c.envs(extra.iter().copied());
    c.output().unwrap()
}

#[test]
fn kubernetes_jobs_validate_and_their_commands_render_and_merge() {
    let Some(bin) = tools_or_skip("kubernetes_jobs_validate_and_their_commands_render_and_merge")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    farm("k8s", &recipe, &out);
    let render = out.join("jobs/k8s-render.yaml");
    let merge = out.join("jobs/k8s-merge.yaml");
    let o = Command::new(bin.join("kubernetes-validate"))
        .arg("--strict")
        .arg(&render)
        .arg(&merge)
        .output()
        .unwrap();
    assert!(
        o.status.success() && text(&o).matches("passed for resource job/").count() == 2,
        "{}",
        text(&o)
    );
    // The validator does reject a Job with a misspelt field.
    let bad = dir.path().join("bad.yaml");
    write_replaced(&render, &bad, "completionMode:", "completionMod:");
    let o = Command::new(bin.join("kubernetes-validate"))
        .arg("--strict")
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!o.status.success(), "a misspelt field fails: {}", text(&o));

    let job = yaml(&bin, &render);
    assert_eq!(job["spec"]["completionMode"], "Indexed");
    assert_eq!(job["spec"]["completions"], 2);
    let pod = &job["spec"]["template"]["spec"];
    assert_eq!(
        pod["volumes"][0]["persistentVolumeClaim"]["claimName"],
        "stereogen-data"
    );
    for index in ["1", "0"] {
        let o = run_container(&pod["containers"][0], &[("JOB_COMPLETION_INDEX", index)]);
        assert!(o.status.success(), "render pod {index}: {}", text(&o));
    }
    let own: Vec<u64> = Manifest::read(&out.join("shards/0001-of-0002/manifest.jsonl"))
        .unwrap()
        .iter()
        .map(|e| e.index)
        .collect();
    assert_eq!(own, vec![1, 3], "index 1 renders shard 1");
    let merge_job = yaml(&bin, &merge);
    let merge_pod = &merge_job["spec"]["template"]["spec"];
    for container in [&merge_pod["initContainers"][0], &merge_pod["containers"][0]] {
        let o = run_container(container, &[]);
        assert!(o.status.success(), "{}: {}", container["name"], text(&o));
    }
    assert_merged(&out);
}

/// `farm SCHEDULER` of 40 samples in 4 tasks without `--threads` (unlike [`farm_cmd`]); the text
/// of FILE in the job directory.
fn job_file(scheduler: &str, recipe: &Path, out: &Path, file: &str, extra: &[&str]) -> String {
    let o = stereogen_cmd(["farm", scheduler, "--count", "40", "--tasks", "4"])
        .arg("--recipe")
        .arg(recipe)
        .arg("--out")
        .arg(out)
        .arg("--stereogen")
        .arg(stereogen_bin())
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "farm {scheduler}: {}", text(&o));
    assert!(
        text(&o).contains("a render task asks for"),
        "farm says what a task asks for: {}",
        text(&o)
    );
    std::fs::read_to_string(out.join("jobs").join(file)).unwrap()
}

/// The `generate` line of a Slurm render script, or the argument list of a YAML file, as words.
fn words(text: &str) -> Vec<String> {
    text.lines()
        .flat_map(|l| match l.trim().strip_prefix("- ") {
            Some(item) => vec![item.to_string()],
            None => l.split_whitespace().map(str::to_string).collect(),
        })
        .map(|w| w.trim_matches(|c| c == '\'' || c == '"').to_string())
        .collect()
}

fn threads_arg(text: &str) -> Option<String> {
    let w = words(text);
    w.windows(2)
        .find(|p| p[0] == "--threads")
        .map(|p| p[1].clone())
}

/// Without --threads or --cpus-per-task a CPU task asks for 8 cores and runs 8 Cycles threads
/// (split over --workers), a GPU task 4 cores and a GPU; Slurm's tasks are signalled GRACE
/// seconds before their limit and requeue; no time limit without --estimate or --time-limit.
#[test]
fn a_farm_task_asks_for_8_cores_and_names_its_threads_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    let sbatch = job_file("slurm", &recipe, &out, "render.sbatch", &[]);
    for line in [
        "#SBATCH --cpus-per-task=8",
        "#SBATCH --signal=TERM@120",
        "#SBATCH --requeue",
    ] {
        assert!(sbatch.lines().any(|l| l == line), "no {line} in:\n{sbatch}");
    }
    assert!(
        !sbatch.contains("--time="),
        "no time limit by default:\n{sbatch}"
    );
    assert_eq!(threads_arg(&sbatch).as_deref(), Some("8"), "{sbatch}");
    let merge = std::fs::read_to_string(out.join("jobs/merge.sbatch")).unwrap();
    assert!(
        !merge.contains("--signal") && !merge.contains("--time="),
        "{merge}"
    );

    let sbatch = job_file(
        "slurm",
        &recipe,
        &out,
        "render.sbatch",
        &["--workers", "2", "--grace", "300"],
    );
    assert!(sbatch.contains("#SBATCH --cpus-per-task=8\n"), "{sbatch}");
    assert!(sbatch.contains("#SBATCH --signal=TERM@300\n"), "{sbatch}");
    assert_eq!(
        threads_arg(&sbatch).as_deref(),
        Some("4"),
        "8 cores / 2 workers"
    );
    let sbatch = job_file(
        "slurm",
        &recipe,
        &out,
        "render.sbatch",
        &["--cpus-per-task", "16", "--workers", "3"],
    );
    assert!(sbatch.contains("#SBATCH --cpus-per-task=16\n"), "{sbatch}");
    assert_eq!(threads_arg(&sbatch).as_deref(), Some("5"));
    let sbatch = job_file(
        "slurm",
        &recipe,
        &out,
        "render.sbatch",
        &["--device", "gpu"],
    );
    assert!(
        sbatch.contains("#SBATCH --cpus-per-task=4\n")
            && sbatch.contains("#SBATCH --gpus-per-task=1\n"),
        "{sbatch}"
    );

    let k8s = job_file("k8s", &recipe, &out, "k8s-render.yaml", &[]);
    assert!(
        k8s.contains("cpu: '8'") || k8s.contains("cpu: \"8\""),
        "{k8s}"
    );
    assert_eq!(threads_arg(&k8s).as_deref(), Some("8"), "{k8s}");
    assert!(!k8s.contains("activeDeadlineSeconds"), "{k8s}");
    let openjd = job_file("openjd", &recipe, &out, "openjd-template.yaml", &[]);
    let vcpu = openjd
        .split("name: amount.worker.vcpu")
        .nth(1)
        .unwrap_or_else(|| panic!("no vCPU host requirement:\n{openjd}"));
    assert!(vcpu.trim_start().starts_with("min: 8"), "{openjd}");
    assert_eq!(threads_arg(&openjd).as_deref(), Some("8"), "{openjd}");
    assert!(!openjd.contains("timeout:"), "{openjd}");
    let openjd = job_file(
        "openjd",
        &recipe,
        &out,
        "openjd-template.yaml",
        &["--device", "gpu", "--gpus-per-task", "2"],
    );
    assert!(
        openjd.contains("name: amount.worker.gpu\n") && openjd.contains("min: 2"),
        "{openjd}"
    );

    // Slurm's forms of --time-limit are read, and written in each scheduler's.
    let sbatch = job_file(
        "slurm",
        &recipe,
        &out,
        "render.sbatch",
        &["--time-limit", "1-2:30"],
    );
    assert!(sbatch.contains("#SBATCH --time=1-02:30:00\n"), "{sbatch}");
    let k8s = job_file(
        "k8s",
        &recipe,
        &out,
        "k8s-render.yaml",
        &["--time-limit", "90"],
    );
    assert!(k8s.contains("activeDeadlineSeconds: 5400\n"), "{k8s}");
    let said = run_fails(
        stereogen_cmd(["farm", "slurm", "--count", "4", "--tasks", "2", "--out"])
            .arg(&out)
            .args(["--time-limit", "soon"]),
    );
    assert!(said.contains("Slurm's MM"), "{said}");
}

/// `--estimate` renders two samples here and sets each scheduler's time limit of the render
/// tasks from them (rounded up to 5 minutes; tiny samples: 5 minutes), not the merge step's; an
/// explicit --time-limit wins; the estimate is printed and written as JOB_DIR/estimate.json.
#[test]
fn farm_estimate_sets_the_render_tasks_time_limit() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    let work = dir.path().join("work");
    let work_arg = work.to_str().unwrap();
    let est = [
        "--estimate",
        "--sample",
        "2",
        "--threads",
        "1",
        "--work",
        work_arg,
    ];
    let sbatch = job_file("slurm", &recipe, &out, "render.sbatch", &est);
    assert!(sbatch.contains("#SBATCH --time=00:05:00\n"), "{sbatch}");
    let merge = std::fs::read_to_string(out.join("jobs/merge.sbatch")).unwrap();
    assert!(
        !merge.contains("--time="),
        "the merge step keeps the scheduler's default: {merge}"
    );
    let e: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("jobs/estimate.json")).unwrap())
            .unwrap();
    assert_eq!(e["time_limit_s"], 300, "{e:#}");
    assert_eq!(e["task"]["tasks"], 4);
    assert_eq!(e["task"]["samples"], 10);
    assert_eq!(
        e["task"]["units"], 1.0,
        "--threads 1, one worker: one core per task"
    );
    assert_eq!(e["measured"]["samples"].as_array().unwrap().len(), 2);
    assert_eq!(
        std::fs::read_dir(&work).unwrap().count(),
        0,
        "the samples are removed"
    );

    let k8s = job_file("k8s", &recipe, &out, "k8s-render.yaml", &est);
    assert!(k8s.contains("activeDeadlineSeconds: 300\n"), "{k8s}");
    let k8s_merge = std::fs::read_to_string(out.join("jobs/k8s-merge.yaml")).unwrap();
    assert!(!k8s_merge.contains("activeDeadlineSeconds"), "{k8s_merge}");
    let openjd = job_file("openjd", &recipe, &out, "openjd-template.yaml", &est);
    assert_eq!(
        openjd.matches("timeout: 300\n").count(),
        1,
        "Render only: {openjd}"
    );

    let mut explicit = est.to_vec();
    explicit.extend(["--time-limit", "3:00:00"]);
    let sbatch = job_file("slurm", &recipe, &out, "render.sbatch", &explicit);
    assert!(sbatch.contains("#SBATCH --time=03:00:00\n"), "{sbatch}");
}
