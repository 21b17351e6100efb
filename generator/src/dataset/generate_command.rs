//! `stereogen generate`'s command line as one typed value: the binary parses it (clap), the farm
//! writes it into job files ([`GenerateCommand::to_args`]), and [`GenerateCommand::options`]
//! turns it into the library's [`GenerateOptions`]. A flag is added here once: its field, its
//! line in `to_args`, and (if the run needs it) its use in `options`. A unit test of the binary
//! checks that parsing `to_args(x)` gives back `x`.
//!
//! The test hook `STEREOGEN_FAULT` is an argument too (hidden, read from the environment by the
//! parser), so the library's `generate` never reads the environment for it.

use std::fmt;
use std::path::PathBuf;
use std::time::Duration;

use clap::builder::{PossibleValuesParser, TypedValueParser};

use super::generate::GenerateOptions;
use super::shard::{ShardArg, resolve_shard};
use crate::plan::Recipe;
use crate::plan::recipe::DEFAULT_PRESET;
use crate::render::FaultPlan;
use crate::render::{Device, WorkerOptions};

/// Which recipe, and the asset folders that override its `[sources]`.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct RecipeArgs {
    /// A built-in preset (crestereo, shapenet, tree, hole, reflective, wmgstereo) or a recipe TOML file.
    #[arg(long, value_name = "PRESET|FILE", default_value = DEFAULT_PRESET)]
    pub recipe: String,
    /// ShapeNetCore root (v1 or v2 layout); overrides the recipe's `sources.shapenet`.
    #[arg(long, value_name = "DIR")]
    pub shapenet: Option<PathBuf>,
    /// A folder of meshes (OBJ, GLB/GLTF, PLY, STL, OFF); overrides `sources.meshes`. The presets'
    /// object categories (which draw `shapenet`) take their meshes from it when no --shapenet is
    /// given; with both, each object draws from one of the two folders with equal chance. Broken
    /// files are skipped and listed in skipped_assets.jsonl.
    #[arg(long, value_name = "DIR")]
    pub meshes: Option<PathBuf>,
    /// A folder of photos used as textures; overrides `sources.textures`.
    #[arg(long, value_name = "DIR")]
    pub textures: Option<PathBuf>,
}

impl RecipeArgs {
    /// The recipe with the command line's asset folders applied.
    pub fn load(&self) -> anyhow::Result<Recipe> {
        let mut recipe = Recipe::load_or_preset(&self.recipe)?;
        if let Some(d) = &self.shapenet {
            recipe.sources.shapenet = Some(d.clone());
        }
        if let Some(d) = &self.meshes {
            recipe.sources.meshes = Some(d.clone());
        }
        if let Some(d) = &self.textures {
            recipe.sources.textures = Some(d.clone());
        }
        Ok(recipe)
    }

    fn push_args(&self, a: &mut Args) {
        a.value("--recipe", &self.recipe);
        a.optional("--shapenet", self.shapenet.as_ref().map(|p| p.display()));
        a.optional("--meshes", self.meshes.as_ref().map(|p| p.display()));
        a.optional("--textures", self.textures.as_ref().map(|p| p.display()));
    }
}

/// How the Blender workers are found, started and supervised.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct RuntimeArgs {
    /// A Blender 4.5 executable to render with (run as `blender -b`). Without it: $STEREOGEN_PYTHON
    /// (a Python that can `import bpy`), then the managed bpy environment under $STEREOGEN_HOME
    /// (default ~/.cache/stereogen), which is installed on first use.
    #[arg(long, value_name = "PATH")]
    pub blender: Option<PathBuf>,
    /// Render on the CPU or on a CUDA/OptiX GPU.
    #[arg(long, default_value_t = Device::Cpu, value_parser = PossibleValuesParser::new(Device::NAMES).map(|s| s.parse::<Device>().expect("listed")))]
    pub device: Device,
    /// Cycles threads per worker [default: the machine's cores divided by --workers].
    #[arg(long, value_name = "N")]
    pub threads: Option<u32>,
    /// Seconds one sample may take before its worker is considered hung, killed and restarted.
    #[arg(long, value_name = "SECS", default_value_t = WorkerOptions::DEFAULT_RENDER_TIMEOUT_S, value_parser = clap::value_parser!(u64).range(1..))]
    pub timeout: u64,
    /// How many times a sample is retried after its worker crashed or hung.
    #[arg(long, value_name = "N", default_value_t = WorkerOptions::DEFAULT_RETRIES)]
    pub retries: u32,
}

impl RuntimeArgs {
    pub fn worker_options(&self) -> WorkerOptions {
        WorkerOptions {
            blender: self.blender.clone(),
            device: self.device,
            threads: self.threads,
            render_timeout: Duration::from_secs(self.timeout),
            retries: self.retries,
            ..WorkerOptions::default()
        }
    }

    fn push_args(&self, a: &mut Args) {
        a.optional("--blender", self.blender.as_ref().map(|p| p.display()));
        a.value("--device", self.device);
        a.optional("--threads", self.threads);
        a.value("--timeout", self.timeout);
        a.value("--retries", self.retries);
    }
}

/// What a render is, apart from where it goes and which part of the range one process takes:
/// the options `stereogen farm` takes too and passes on to every task as they are.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct TaskArgs {
    #[command(flatten)]
    pub recipe: RecipeArgs,
    /// Number of samples (of the whole dataset, for a farm).
    #[arg(long, value_name = "N")]
    pub count: u64,
    /// Dataset seed: sample i is a pure function of (recipe, seed, i).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// First sample index.
    #[arg(long, value_name = "INDEX", default_value_t = 0)]
    pub start: u64,
    /// Blender worker processes rendering in parallel (per farm task).
    #[arg(long, value_name = "K", default_value_t = 1)]
    pub workers: usize,
    #[command(flatten)]
    pub runtime: RuntimeArgs,
}

impl TaskArgs {
    fn push_args(&self, a: &mut Args) {
        self.recipe.push_args(a);
        a.value("--count", self.count);
        a.value("--seed", self.seed);
        a.value("--start", self.start);
        a.value("--workers", self.workers);
        self.runtime.push_args(a);
    }
}

/// `stereogen generate`'s arguments.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct GenerateCommand {
    /// Output dataset directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    #[command(flatten)]
    pub task: TaskArgs,
    /// Render only indices i with i % N == K, into OUT/shards/KKKK-of-NNNN/ (one farm task per
    /// shard). `auto`: K and N from the scheduler (STEREOGEN_SHARD=K/N, Slurm array, Kubernetes
    /// Indexed Job, AWS Batch array).
    #[arg(long, value_name = "K/N|auto", value_parser = clap::value_parser!(ShardArg))]
    pub shard: Option<ShardArg>,
    /// With --shard auto: the number of shards where the scheduler does not say it
    /// (Kubernetes; also STEREOGEN_SHARD_COUNT).
    #[arg(long, value_name = "N", requires = "shard")]
    pub shards: Option<u64>,
    /// Take the output directory's lock even if another process seems to hold it.
    #[arg(long)]
    pub break_lock: bool,
    /// Hide the progress bar.
    #[arg(long)]
    pub no_progress: bool,
    /// Test hook (see [`FaultPlan`]); normally given as STEREOGEN_FAULT.
    #[arg(long = "test-fault", env = "STEREOGEN_FAULT", hide = true, value_name = "FAULTS", value_parser = clap::value_parser!(FaultPlan))]
    pub fault: Option<FaultPlan>,
}

impl GenerateCommand {
    /// `generate` and its arguments: what a user would type for this value.
    pub fn to_args(&self) -> Vec<String> {
        let mut a = Args(vec!["generate".into()]);
        a.value("--out", self.out.display());
        self.task.push_args(&mut a);
        a.optional("--shard", self.shard.map(ShardArg::to_arg));
        a.optional("--shards", self.shards);
        a.flag("--break-lock", self.break_lock);
        a.flag("--no-progress", self.no_progress);
        a.optional("--test-fault", self.fault.as_ref());
        a.0
    }

    /// The library's options for this command: the recipe loaded, an automatic shard resolved
    /// (where it came from goes to the log, a farm task's first line).
    pub fn options(&self) -> anyhow::Result<GenerateOptions> {
        let t = &self.task;
        let mut opts = GenerateOptions::new(&self.out, t.recipe.load()?, t.seed, t.count);
        opts.start = t.start;
        if let Some(arg) = self.shard {
            let detected = resolve_shard(arg, self.shards)?;
            if arg == ShardArg::Auto {
                tracing::info!("shard {} ({})", detected.shard, detected.source);
            }
            opts.shard = Some(detected.shard);
        }
        opts.break_lock = self.break_lock;
        opts.workers = t.workers;
        opts.worker_options = t.runtime.worker_options();
        opts.faults = self.fault.clone().unwrap_or_default();
        Ok(opts)
    }
}

/// An argument list under construction.
struct Args(Vec<String>);

impl Args {
    fn value(&mut self, flag: &str, value: impl fmt::Display) {
        self.0.extend([flag.to_string(), value.to_string()]);
    }

    fn optional(&mut self, flag: &str, value: Option<impl fmt::Display>) {
        if let Some(v) = value {
            self.value(flag, v);
        }
    }

    fn flag(&mut self, flag: &str, set: bool) {
        if set {
            self.0.push(flag.to_string());
        }
    }
}
