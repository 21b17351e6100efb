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
use crate::render::Device;

/// Cores a CPU render task asks for when neither `--cpus-per-task` nor `--threads` is given.
/// Cycles' path tracing scales almost linearly with threads, so a sample's core-seconds hardly
/// change with the count, while its wall time (and so the work lost to a preemption, and the
/// length of the time limit) shrinks; the single-threaded parts of a sample (scene build,
/// saving) waste a growing share of a task above about 8. Eight cores also pack the common
/// 32-128-core farm nodes without remainder.
pub const DEFAULT_CPU_TASK_CORES: u32 = 8;
/// Cores a GPU render task asks for by default: the scene build, the depth passes' host work,
/// saving and checking the files; Cycles renders colour on the GPU.
pub const DEFAULT_GPU_TASK_CORES: u32 = 4;

/// A task's wall-time limit, whole seconds. Parsed from Slurm's forms (`MM`, `MM:SS`,
/// `HH:MM:SS`, `D-HH`, `D-HH:MM`, `D-HH:MM:SS`); written as Slurm's `[D-]HH:MM:SS` or as seconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct TimeLimit(pub u64);

impl TimeLimit {
    pub fn seconds(self) -> u64 {
        self.0
    }

    /// `D-HH:MM:SS` (days only when there are any).
    pub fn slurm(self) -> String {
        let s = self.0;
        let (d, h, m, s) = (s / 86_400, s / 3_600 % 24, s / 60 % 60, s % 60);
        if d > 0 {
            format!("{d}-{h:02}:{m:02}:{s:02}")
        } else {
            format!("{h:02}:{m:02}:{s:02}")
        }
    }

    /// `seconds` rounded up to a whole number of `step` seconds.
    pub fn round_up(seconds: f64, step: u64) -> Self {
        let steps = (seconds.max(1.0) / step as f64).ceil() as u64;
        Self(steps.max(1) * step)
    }
}

impl std::str::FromStr for TimeLimit {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "time limit {text:?}: use Slurm's MM, MM:SS, HH:MM:SS, D-HH, D-HH:MM or D-HH:MM:SS"
            )
        };
        let num = |p: &str| p.parse::<u64>().map_err(|_| bad());
        let (days, rest) = match text.split_once('-') {
            Some((d, rest)) => (Some(num(d)?), rest),
            None => (None, text),
        };
        let parts = rest
            .split(':')
            .map(num)
            .collect::<Result<Vec<u64>, String>>()?;
        let seconds = match (days, parts.as_slice()) {
            (None, [m]) => m * 60,
            (None, [m, s]) => m * 60 + s,
            (None, [h, m, s]) => h * 3600 + m * 60 + s,
            (Some(d), [h]) => d * 86_400 + h * 3600,
            (Some(d), [h, m]) => d * 86_400 + h * 3600 + m * 60,
            (Some(d), [h, m, s]) => d * 86_400 + h * 3600 + m * 60 + s,
            _ => return Err(bad()),
        };
        if seconds == 0 {
            return Err(format!("time limit {text:?} is zero"));
        }
        Ok(Self(seconds))
    }
}

/// The exit code of a `generate` that stopped on SIGTERM/SIGINT before finishing its range
/// (EX_TEMPFAIL: nothing is wrong, run the same command again to resume). The job files treat
/// it as "requeue this task": Slurm's script requeues itself, the Kubernetes Job's pod failure
/// policy does not count it against the retry limit. The one definition is
/// [`crate::interrupt::EXIT_INTERRUPTED`], which `generate` exits with.
pub const INTERRUPTED_EXIT_CODE: i32 = crate::interrupt::EXIT_INTERRUPTED as i32;

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
    /// CPU cores a task asks for [default: see [`FarmOptions::cpus`]].
    pub cpus_per_task: Option<u32>,
    /// Memory a task asks for (`16G`; Kubernetes: `16Gi`).
    pub memory: Option<String>,
    /// Wall-time limit of a render task (Slurm `--time`, Kubernetes pod
    /// `activeDeadlineSeconds`, OpenJD action `timeout`): `--time-limit`, or set from
    /// `--estimate`. `None`: the scheduler's default.
    pub time_limit: Option<TimeLimit>,
    /// Wall-time limit of the merge step: an explicit `--time-limit` only (an estimate is about
    /// rendering).
    pub merge_time_limit: Option<TimeLimit>,
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

    /// Cores a task asks for: `--cpus-per-task`; else workers × `--threads`; else
    /// [`DEFAULT_CPU_TASK_CORES`] (a CPU render) or [`DEFAULT_GPU_TASK_CORES`] (a GPU render),
    /// at least one per worker.
    pub fn cpus(&self) -> u32 {
        let workers = self.task.workers.max(1) as u32;
        match (self.cpus_per_task, self.task.runtime.threads) {
            (Some(c), _) => c.max(1),
            (None, Some(t)) => (workers * t).max(1),
            (None, None) => {
                let default = match self.task.runtime.device {
                    Device::Cpu => DEFAULT_CPU_TASK_CORES,
                    Device::Gpu => DEFAULT_GPU_TASK_CORES,
                };
                default.max(workers)
            }
        }
    }

    /// Cycles threads of each worker, always written into the task's command line so a worker
    /// uses what the task asked for, not what it sees of the node: `--threads`, else the task's
    /// cores divided by the workers (at least 1).
    pub fn threads(&self) -> u32 {
        self.task
            .runtime
            .threads
            .unwrap_or_else(|| (self.cpus() / self.task.workers.max(1) as u32).max(1))
    }

    /// GPUs a render task asks for: `--gpus-per-task`, else 1 when it renders on the GPU.
    pub fn gpus(&self) -> Option<u32> {
        self.gpus_per_task
            .or((self.task.runtime.device == Device::Gpu).then_some(1))
    }

    /// What a render task asks for, in words (for `farm`'s output and the job files' comments).
    pub fn resources(&self) -> String {
        let device = self
            .gpus()
            .map_or(String::new(), |g| format!(", {g} GPU(s)"));
        let limit = self
            .time_limit
            .map_or("the scheduler's default time limit".to_string(), |t| {
                format!("a time limit of {}", t.slurm())
            });
        format!(
            "{} core(s) ({} worker(s) × {} Cycles thread(s)){device}, {limit}",
            self.cpus(),
            self.task.workers,
            self.threads()
        )
    }

    /// The `generate` every render task runs, with `shard` (each scheduler says its own) and
    /// the recipe file in the job directory.
    pub fn generate_command(&self, shard: Option<ShardArg>) -> GenerateCommand {
        let mut task = self.task.clone();
        task.runtime.threads = Some(self.threads());
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

#[cfg(test)]
mod tests {
    use super::TimeLimit;

    #[test]
    fn time_limits_read_every_slurm_form_and_write_slurms_canonical_one() {
        for (text, seconds, slurm) in [
            ("90", 5_400, "01:30:00"),
            ("90:30", 5_430, "01:30:30"),
            ("12:00:00", 43_200, "12:00:00"),
            ("2-3", 183_600, "2-03:00:00"),
            ("2-03:15", 184_500, "2-03:15:00"),
            ("1-00:00:01", 86_401, "1-00:00:01"),
        ] {
            let t: TimeLimit = text.parse().unwrap();
            assert_eq!(
                (t.seconds(), t.slurm().as_str()),
                (seconds, slurm),
                "{text}"
            );
            assert_eq!(t.slurm().parse::<TimeLimit>().unwrap(), t);
        }
        for bad in ["", "1:2:3:4", "a", "1-", "0", "-5", "1-2-3"] {
            assert!(bad.parse::<TimeLimit>().is_err(), "{bad:?}");
        }
        assert_eq!(TimeLimit::round_up(301.0, 300).seconds(), 600);
        assert_eq!(TimeLimit::round_up(0.2, 300).seconds(), 300);
    }
}
