//! `stereogen farm slurm|k8s|openjd`: job files that render one dataset with many tasks.
//!
//! Each scheduler's file is built from typed structures ([`slurm`], [`k8s`], [`openjd`]) and
//! serialised; what every task runs is the same `stereogen generate` a user would type
//! ([`FarmOptions::generate_command`], serialised by [`GenerateCommand::to_args`]), with the shard taken from the scheduler (`--shard auto`) or
//! the task parameter, so re-submitting the same file resumes. After the render tasks, a merge
//! step runs `stereogen merge` and `stereogen stats --check` on the shared output; with
//! [`FarmOptions::webdataset`] the merge also writes the dataset as WebDataset shards.
//!
//! The recipe is written once into the job directory (`recipe.toml`, the loaded recipe with the
//! command line's asset folders applied), so every task reads the same recipe from shared storage.

pub mod k8s;
pub mod openjd;
pub mod slurm;

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use crate::dataset::generate_command::{GenerateCommand, RecipeArgs, TaskArgs};
use crate::dataset::merge::{WebDatasetTarget, check_webdataset_dir};
use crate::dataset::shard::ShardArg;
use crate::plan::Recipe;

/// The exit code of a `generate` that stopped on SIGTERM/SIGINT before finishing its range
/// (EX_TEMPFAIL: nothing is wrong, run the same command again to resume). The job files treat
/// it as "requeue this task": Slurm's script requeues itself, the Kubernetes Job's pod failure
/// policy does not count it against the retry limit. The one definition is
/// [`crate::dataset::interrupt::EXIT_INTERRUPTED`], which `generate` exits with.
pub const INTERRUPTED_EXIT_CODE: i32 = crate::dataset::interrupt::EXIT_INTERRUPTED as i32;

/// What a farm run renders and how its tasks are shaped.
#[derive(Debug, Clone)]
pub struct FarmOptions {
    /// The recipe, loaded (with `--shapenet/--meshes/--textures` applied).
    pub recipe: Recipe,
    /// What every task renders (samples `start .. start + count` of the whole dataset, the
    /// workers and their runtime), passed on to its `generate` as it is; the recipe argument is
    /// replaced by [`FarmOptions::recipe_path`].
    pub task: TaskArgs,
    /// Render tasks (= shards).
    pub tasks: u64,
    /// The shared output directory, as the tasks see it.
    pub out: PathBuf,
    pub gpus_per_task: Option<u32>,
    /// CPU cores a task asks for [default: workers × threads, at least 1].
    pub cpus_per_task: Option<u32>,
    /// Memory a task asks for (`16G`; Kubernetes: `16Gi`).
    pub memory: Option<String>,
    /// Wall-time limit of a task (Slurm `--time`, e.g. `12:00:00`).
    pub time_limit: Option<String>,
    pub partition: Option<String>,
    /// Container image (Kubernetes).
    pub image: String,
    /// PersistentVolumeClaim of the shared output (Kubernetes).
    pub volume_claim: String,
    /// Tasks running at once.
    pub max_parallel: Option<u64>,
    /// The `stereogen` executable the tasks run.
    pub stereogen: PathBuf,
    /// Job name prefix.
    pub name: String,
    /// Seconds between SIGTERM and SIGKILL that the job files ask for.
    pub grace_s: u64,
    /// `merge --verify`: recompute every checksum in the merge step.
    pub verify: bool,
    /// `merge --webdataset DIR ...`: the merge step also writes the dataset as WebDataset shards
    /// into DIR (absolute, like `out`).
    pub webdataset: Option<WebDatasetTarget>,
    /// Extra environment of every task (`KEY=VALUE`), e.g. `STEREOGEN_HOME`.
    pub env: Vec<(String, String)>,
    /// Where the job files (and the recipe) are written [default: `OUT/jobs`].
    pub job_dir: PathBuf,
}

impl FarmOptions {
    pub fn check(&self) -> anyhow::Result<()> {
        if self.tasks == 0 {
            bail!("--tasks must be at least 1");
        }
        if self.task.count == 0 {
            bail!("--count must be at least 1");
        }
        if self.tasks > self.task.count {
            bail!(
                "--tasks {} is more than --count {}: some tasks would have nothing to render",
                self.tasks,
                self.task.count
            );
        }
        if self.max_parallel == Some(0) {
            bail!("--max-parallel must be at least 1");
        }
        if !self.out.is_absolute() {
            bail!(
                "--out {} must be an absolute path: every task and the merge step must find the same directory",
                self.out.display()
            );
        }
        if let Some(t) = &self.webdataset {
            if !t.dir.is_absolute() {
                bail!(
                    "--webdataset {} must be an absolute path: the merge step runs elsewhere",
                    t.dir.display()
                );
            }
            check_webdataset_dir(&self.out, &t.dir)?;
        }
        for (k, _) in &self.env {
            if k.is_empty()
                || !k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                || k.starts_with(|c: char| c.is_ascii_digit())
            {
                bail!("--env {k:?}: not an environment variable name");
            }
        }
        Ok(())
    }

    /// The recipe file every task reads: `JOB_DIR/recipe.toml`.
    pub fn recipe_path(&self) -> PathBuf {
        self.job_dir.join("recipe.toml")
    }

    /// Cores a task asks for.
    pub fn cpus(&self) -> u32 {
        self.cpus_per_task.unwrap_or_else(|| {
            (self.task.workers as u32 * self.task.runtime.threads.unwrap_or(1)).max(1)
        })
    }

    /// The `generate` every render task runs, with `shard` (each scheduler says its own) and
    /// the recipe file in the job directory.
    pub fn generate_command(&self, shard: Option<ShardArg>) -> GenerateCommand {
        let mut task = self.task.clone();
        task.recipe = RecipeArgs {
            recipe: path(&self.recipe_path()),
            shapenet: None,
            meshes: None,
            textures: None,
        };
        GenerateCommand {
            out: self.out.clone(),
            task,
            shard,
            shards: None,
            break_lock: false,
            no_progress: true,
            fault: None,
        }
    }

    /// `merge OUT [--verify] [--webdataset DIR --shard-size B --shuffle-seed S --splits ...]`.
    pub fn merge_args(&self) -> Vec<String> {
        let mut a = vec!["merge".to_string(), path(&self.out)];
        if self.verify {
            a.push("--verify".into());
        }
        if let Some(t) = &self.webdataset {
            a.extend(t.to_args());
        }
        a
    }

    /// `stats OUT --check`.
    pub fn check_args(&self) -> Vec<String> {
        vec!["stats".into(), path(&self.out), "--check".into()]
    }
}

fn path(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// Which scheduler's files to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scheduler {
    Slurm,
    Kubernetes,
    OpenJd,
}

/// Writes the recipe and the scheduler's job files into the job directory; returns the files
/// written, the one to submit first.
pub fn write_job_files(opts: &FarmOptions, scheduler: Scheduler) -> anyhow::Result<Vec<PathBuf>> {
    opts.check()?;
    if let Some(t) = &opts.webdataset
        && scheduler == Scheduler::Kubernetes
        && !t.dir.starts_with(&opts.out)
    {
        bail!(
            "--webdataset {}: a Kubernetes pod sees only the volume mounted at --out {}; put the shards under it",
            t.dir.display(),
            opts.out.display()
        );
    }
    std::fs::create_dir_all(&opts.job_dir)
        .with_context(|| format!("cannot create {}", opts.job_dir.display()))?;
    let recipe = toml::to_string(&opts.recipe).context("cannot write the recipe as TOML")?;
    write(&opts.recipe_path(), recipe.as_bytes(), false)?;
    let files = match scheduler {
        Scheduler::Slurm => slurm::files(opts)?,
        Scheduler::Kubernetes => k8s::files(opts)?,
        Scheduler::OpenJd => openjd::files(opts)?,
    };
    let mut written = Vec::new();
    for (name, text, executable) in files {
        let p = opts.job_dir.join(name);
        write(&p, text.as_bytes(), executable)?;
        written.push(p);
    }
    Ok(written)
}

fn write(path: &Path, bytes: &[u8], executable: bool) -> anyhow::Result<()> {
    stereo_io::write_bytes_atomically(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))?;
    if executable {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755))
            .with_context(|| format!("cannot make {} executable", path.display()))?;
    }
    Ok(())
}

/// A file of a job: its name in the job directory, its text, whether it is executable.
pub type JobFile = (String, String, bool);
