//! The kernel census: every GPU kernel a process compiled, by family and by cause, with its shape
//! key — what a cold start costs, itemised.
//!
//! CubeCL compiles a kernel the first time it is launched with a new id (its type, its
//! compile-time configuration — shapes where they are compiled in — and its cube size), and
//! autotuning compiles and times every candidate of an operation before the fastest is kept.
//! With the census on, CubeCL's compilation log (every compiled kernel's name and id) and its
//! autotune log ("Tuning KEY" when a tuning begins, "Fastest result NAME-KEY" when it ends) are
//! routed through `log` to [`layer`], which keeps one record per compiled kernel:
//!
//! * **family**: from the kernel's type path (convolution forward/backward, matmul, reduce,
//!   fused element-wise, AGCL, upsampling, layout, …; see [`family_of`]);
//! * **cause**: `tuning` when it was compiled while an autotuning was open (a candidate that was
//!   measured; the winner of each tuning is among them, and later runs from the same binary),
//!   otherwise `run` (a kernel the work launched). The compilation log reaches the census
//!   through CubeCL's logging thread, so a kernel compiled just before a tuning begins can be
//!   counted as a tuning one; the totals are exact, the split is the log's order;
//! * **key**: CubeCL's kernel id on one line (type, cube size, compile-time configuration).
//!
//! `crestereo warmup` always takes the census and prints it; any GPU command does with
//! `CRESTEREO_KERNEL_CENSUS=FILE` (the JSON goes to FILE) or `=1` (beside the kernel cache, in
//! `<cache>/census/`).

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tracing::field::{Field, Visit};
use tracing_subscriber::Layer;
use tracing_subscriber::filter::Targets;

/// Where CubeCL's log sink writes its messages through `log` (the target the census listens on).
const SINK_TARGET: &str = "cubecl_common::config::logger";
/// Where CubeCL's tuner says "Tuning KEY".
const TUNER_TARGET: &str = "cubecl_runtime::tune";

/// Why a kernel was compiled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Cause {
    /// Launched by the work itself.
    Run,
    /// Compiled while an autotuning was open: a candidate measured (and maybe kept).
    Tuning,
}

/// One compiled kernel.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CompiledKernel {
    pub family: String,
    pub cause: Cause,
    /// The part of the command that compiled it (e.g. `training step`, `inference 128x192`).
    pub phase: String,
    /// Seconds since the census began.
    pub at_s: f64,
    /// The kernel's name as CubeCL gives it.
    pub name: String,
    /// CubeCL's kernel id on one line: the shape key.
    pub key: String,
}

/// Counts of one family.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    pub run: usize,
    pub tuning: usize,
}

impl Counts {
    pub fn total(&self) -> usize {
        self.run + self.tuning
    }
}

/// What a process compiled.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Census {
    /// Every compiled kernel, in order.
    pub kernels: Vec<CompiledKernel>,
    /// Autotunings finished (each kept one candidate).
    pub tunings: usize,
    /// Per family, then in total.
    pub by_family: BTreeMap<String, Counts>,
    pub total: Counts,
}

impl Census {
    fn from_kernels(kernels: Vec<CompiledKernel>, tunings: usize) -> Self {
        let mut by_family: BTreeMap<String, Counts> = BTreeMap::new();
        let mut total = Counts::default();
        for k in &kernels {
            let c = by_family.entry(k.family.clone()).or_default();
            match k.cause {
                Cause::Run => {
                    c.run += 1;
                    total.run += 1;
                }
                Cause::Tuning => {
                    c.tuning += 1;
                    total.tuning += 1;
                }
            }
        }
        Self {
            kernels,
            tunings,
            by_family,
            total,
        }
    }

    /// How many kernels were compiled in `phase`.
    pub fn count_in(&self, phase: &str) -> usize {
        self.kernels.iter().filter(|k| k.phase == phase).count()
    }

    /// A table: one line per family (run, tuning, all), then the total.
    pub fn table(&self) -> String {
        let mut out = format!(
            "  {:<28} {:>6} {:>7} {:>6}\n",
            "family", "run", "tuning", "all"
        );
        for (family, c) in &self.by_family {
            out += &format!(
                "  {family:<28} {:>6} {:>7} {:>6}\n",
                c.run,
                c.tuning,
                c.total()
            );
        }
        out += &format!(
            "  {:<28} {:>6} {:>7} {:>6}   ({} autotunings)\n",
            "all",
            self.total.run,
            self.total.tuning,
            self.total.total(),
            self.tunings
        );
        out
    }

    /// Reads a census JSON written by [`write`](Census::write).
    pub fn read(path: &Path) -> anyhow::Result<Census> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// Writes the census as JSON (one durable write).
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
        }
        let bytes = serde_json::to_vec_pretty(self)?;
        stereo_io::write_bytes_atomically(path, &bytes)?;
        Ok(())
    }
}

struct Recorder {
    started: Instant,
    phase: String,
    /// Keys of the autotunings open now.
    open: HashSet<String>,
    tunings: usize,
    kernels: Vec<CompiledKernel>,
}

static RECORDER: Mutex<Option<Recorder>> = Mutex::new(None);

fn recorder() -> std::sync::MutexGuard<'static, Option<Recorder>> {
    RECORDER.lock().unwrap_or_else(|e| e.into_inner())
}

/// Starts the census (call before the first GPU use; [`configure`] must be applied too).
pub fn start() {
    *recorder() = Some(Recorder {
        started: Instant::now(),
        phase: String::new(),
        open: HashSet::new(),
        tunings: 0,
        kernels: Vec::new(),
    });
}

/// Whether the census is on.
pub fn active() -> bool {
    recorder().is_some()
}

/// Names the part of the work the kernels compiled from now on belong to.
pub fn set_phase(phase: &str) {
    if let Some(r) = recorder().as_mut() {
        r.phase = phase.to_string();
    }
}

/// What was compiled so far (empty when the census is off).
pub fn snapshot() -> Census {
    match recorder().as_ref() {
        Some(r) => Census::from_kernels(r.kernels.clone(), r.tunings),
        None => Census::default(),
    }
}

/// `CRESTEREO_KERNEL_CENSUS`: `None` when unset or `0`; `Some(None)` for `1` (beside the kernel
/// cache), `Some(Some(FILE))` for any other value.
pub fn requested() -> Option<Option<PathBuf>> {
    let v = std::env::var_os("CRESTEREO_KERNEL_CENSUS")?;
    match v.to_str() {
        Some("" | "0") => None,
        Some("1") => Some(None),
        _ => Some(Some(PathBuf::from(v))),
    }
}

/// The census file of a run beside the kernel cache: `<cache>/census/<command>-<time>-<pid>.json`.
pub fn beside_cache(cache: &Path, command: &str) -> PathBuf {
    let ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    cache
        .join("census")
        .join(format!("{command}-{ms}-{}.json", std::process::id()))
}

/// Turns on the logs the census reads: the compilation log at its full level (name and id of
/// every compiled kernel) and the autotune log, both sent to `log` at trace level, where
/// [`layer`] takes them (and the terminal's log, at info, does not show them).
#[cfg(feature = "kernel-cache")]
pub fn configure(config: &mut cubecl_runtime::config::CubeClRuntimeConfig) {
    use cubecl_common::config::logger::LogCrateLevel;
    use cubecl_runtime::config::autotune::AutotuneLogLevel;
    use cubecl_runtime::config::compilation::CompilationLogLevel;
    config.compilation.logger.level = CompilationLogLevel::Full;
    config.compilation.logger.log = Some(LogCrateLevel::Trace);
    config.autotune.logger.level = AutotuneLogLevel::Minimal;
    config.autotune.logger.log = Some(LogCrateLevel::Trace);
}

/// The tracing layer that feeds the census (does nothing while it is off).
pub fn layer<S>() -> impl Layer<S>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    CensusLayer.with_filter(
        Targets::new()
            .with_target(SINK_TARGET, tracing::Level::TRACE)
            .with_target(TUNER_TARGET, tracing::Level::INFO),
    )
}

struct CensusLayer;

impl<S: tracing::Subscriber> Layer<S> for CensusLayer {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        let mut guard = recorder();
        let Some(r) = guard.as_mut() else {
            return;
        };
        let mut message = MessageText(String::new());
        event.record(&mut message);
        r.take(&message.0);
    }
}

struct MessageText(String);

impl Visit for MessageText {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.0 = value.to_string();
        }
    }
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl Recorder {
    fn take(&mut self, message: &str) {
        if let Some(rest) = message.strip_prefix("[START_KERNEL_COMPILATION]") {
            let (name, key) = parse_compilation(rest);
            let cause = if self.open.is_empty() {
                Cause::Run
            } else {
                Cause::Tuning
            };
            self.kernels.push(CompiledKernel {
                family: family_of(&key, &name).to_string(),
                cause,
                phase: self.phase.clone(),
                at_s: self.started.elapsed().as_secs_f64(),
                name,
                key,
            });
        } else if let Some(key) = message.strip_prefix("Tuning ") {
            self.open.insert(key.trim().to_string());
        } else if let Some(rest) = message.strip_prefix("Fastest result ") {
            // "Fastest result NAME-KEY. …": the key of the tuning that ended.
            let head = rest.split(". ").next().unwrap_or(rest);
            let closed = self
                .open
                .iter()
                .find(|k| head.ends_with(k.as_str()))
                .cloned();
            match closed {
                Some(k) => {
                    self.open.remove(&k);
                }
                // A key printed differently: close one open tuning, never leave them all open.
                None => {
                    if let Some(k) = self.open.iter().next().cloned() {
                        self.open.remove(&k);
                    }
                }
            }
            self.tunings += 1;
        }
    }
}

/// The name and the one-line id of a full compilation-log entry (the text after its start
/// marker: `name: …`, `id: KernelId { … }`, `source: …`).
fn parse_compilation(text: &str) -> (String, String) {
    let mut name = String::new();
    let mut id = String::new();
    let mut in_id = false;
    for line in text.lines() {
        if let Some(n) = line.strip_prefix("name: ") {
            name = n.trim().to_string();
        } else if let Some(i) = line.strip_prefix("id: ") {
            id.push_str(i.trim());
            in_id = true;
        } else if line.starts_with("source:") {
            break;
        } else if in_id {
            id.push(' ');
            id.push_str(line.trim());
        }
    }
    let id = id.split_whitespace().collect::<Vec<_>>().join(" ");
    (name, id)
}

/// The family of a kernel, from its type path (in its id) or its name.
pub fn family_of(key: &str, name: &str) -> &'static str {
    // The id's `type: …` field is the kernel's full type path; the name is the short one.
    let path = key
        .split("type: ")
        .nth(1)
        .and_then(|t| t.split(", address_type").next())
        .unwrap_or(name)
        .to_ascii_lowercase();
    let has = |s: &str| path.contains(s);
    if has("crestereo") {
        if has("agcl") {
            "agcl"
        } else {
            "crestereo (other)"
        }
    } else if has("fusion") || has("fuse") {
        if has("reduce") {
            "fused reduce"
        } else if has("matmul") {
            "fused matmul"
        } else {
            "fused element-wise"
        }
    } else if has("backward_data") || has("backward_weight") || has("conv_transpose") {
        "convolution backward"
    } else if has("conv") {
        "convolution forward"
    } else if has("matmul") || has("gemv") || has("gemm") {
        "matmul"
    } else if has("reduce") || has("argmax") || has("argmin") || has("sum") {
        "reduce"
    } else if has("interpolate") || has("upsample") || has("grid_sample") {
        "upsampling"
    } else if has("pool") {
        "pooling"
    } else if has("random") || has("prng") {
        "random"
    } else if has("full_kernel") || has("full_device") || has("::fill") {
        "fill (zeros, constants)"
    } else if [
        "contiguous",
        "copy",
        "slice",
        "cat",
        "gather",
        "scatter",
        "select",
        "index",
    ]
    .iter()
    .chain(&["permute", "reshape"])
    .any(|s| has(s))
    {
        "layout (copy, slice, gather)"
    } else if has("cast") {
        "cast"
    } else if has("unary") || has("binary") || has("clamp") || has("comparison") || has("mask") {
        "element-wise"
    } else {
        "other"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ENTRY: &str = "\nname: reduce_kernel\nid: KernelId {\n    type: cubek_reduce::launch::ReduceKernel<f32>,\n    address_type: U32,\n    cube_dim: CubeDim { x: 256, y: 1, z: 1 },\n    mode: Checked,\n    info: Some(\n        (7, 128),\n    ),\n}\nsource:\n```spirv\nOpCapability Shader\n```\n[END_KERNEL_COMPILATION]\n";

    #[test]
    fn a_compilation_entry_gives_its_name_and_one_line_key() {
        let (name, key) = parse_compilation(ENTRY);
        assert_eq!(name, "reduce_kernel");
        assert_eq!(
            key,
            "KernelId { type: cubek_reduce::launch::ReduceKernel<f32>, address_type: U32, cube_dim: CubeDim { x: 256, y: 1, z: 1 }, mode: Checked, info: Some( (7, 128), ), }"
        );
        assert_eq!(family_of(&key, &name), "reduce");
        for (path, family) in [
            (
                "cubek_matmul::components::batch::partitioned_matmul::matmul::matmul_entry::MatmulEntry<f32>",
                "matmul",
            ),
            (
                "burn_cubecl_fusion::optim::elemwise::optimization::elemwise_fuse::ElemwiseFuse<f32>",
                "fused element-wise",
            ),
            (
                "burn_cubecl_fusion::optim::reduce::optimization::reduce_kernel_fused::ReduceKernelFused<f32>",
                "fused reduce",
            ),
            (
                "burn_cubecl::kernel::index::slice_assign::slice_assign_kernel::SliceAssignKernel<f32>",
                "layout (copy, slice, gather)",
            ),
            (
                "burn_cubecl::ops::numeric::full_device_dtype::full_kernel::FullKernel<f32>",
                "fill (zeros, constants)",
            ),
            (
                "burn_cubecl::kernel::pool::pool2d::pool2d_direct::Pool2dDirect<f32>",
                "pooling",
            ),
            ("cubek_random::base::prng_kernel::PrngKernel<f32>", "random"),
            (
                "crestereo::ops::agcl::cube::warp_kernel::WarpKernel<f32>",
                "agcl",
            ),
            (
                "burn_cubecl::kernel::binary::kernel_binop::KernelBinop<f32>",
                "element-wise",
            ),
        ] {
            let key = format!(
                "KernelId {{ type: {path}, address_type: U32, cube_dim: CubeDim {{ x: 1 }} }}"
            );
            assert_eq!(family_of(&key, ""), family, "{path}");
        }
    }

    #[test]
    fn kernels_compiled_inside_a_tuning_count_as_tuning() {
        let mut r = Recorder {
            started: Instant::now(),
            phase: "p".into(),
            open: HashSet::new(),
            tunings: 0,
            kernels: Vec::new(),
        };
        let entry = format!("[START_KERNEL_COMPILATION]{ENTRY}");
        r.take(&entry);
        r.take("Tuning key-a");
        r.take(&entry);
        r.take(&entry);
        r.take("Fastest result simple_unit-key-a. \n Top 3 times: []");
        r.take(&entry);
        let c = Census::from_kernels(r.kernels.clone(), r.tunings);
        assert_eq!(c.total, Counts { run: 2, tuning: 2 });
        assert_eq!(c.tunings, 1);
        assert!(r.open.is_empty());
        assert_eq!(c.by_family["reduce"].total(), 4);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("census").join("x.json");
        c.write(&path).unwrap();
        let back = Census::read(&path).unwrap();
        assert_eq!(back.total, c.total);
        assert_eq!(back.kernels.len(), 4);
    }
}
