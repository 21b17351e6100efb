//! Projecting a measurement onto a whole run: per category and per task, with the spread of
//! the sample times (printed by [`Estimate::text`]).

use std::collections::BTreeMap;

use serde::Serialize;

use super::cost::{Measurement, SampleCost, median};
use crate::farm::TimeLimit;
use crate::plan::recipe::CategoryRecipe;
use crate::plan::{Recipe, scene_category};
use crate::render::Device;

/// Ranges up to this many samples get their categories counted exactly (planning a sample's
/// category is a hash and a draw); longer ones are split by the weights.
pub const EXACT_COUNT_LIMIT: u64 = 5_000_000;
/// A time limit set from an estimate is this many times the largest task's projected wall time
/// (plus the grace period), rounded up to [`TIME_LIMIT_STEP_S`]: room for slower cores, a busy
/// shared filesystem and scenes costlier than the few measured.
pub const TIME_LIMIT_SAFETY: f64 = 1.5;
pub const TIME_LIMIT_STEP_S: u64 = 300;

/// min / median / max / mean and the standard error of the mean.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Spread {
    pub min: f64,
    pub median: f64,
    pub max: f64,
    pub mean: f64,
    /// Standard error of the mean (`None` from one value).
    pub sem: Option<f64>,
}

impl Spread {
    pub fn of(v: &[f64]) -> Self {
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let sem = (v.len() > 1).then(|| {
            let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
            (var / n).sqrt()
        });
        Self {
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            median: median(v),
            max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            mean,
            sem,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CategoryEstimate {
    pub name: String,
    pub weight: f64,
    /// Samples of this category in the range.
    pub samples: u64,
    /// Samples measured.
    pub measured: usize,
    /// Measured wall seconds per sample here (worker start-up excluded).
    pub seconds: Option<Spread>,
    /// Device seconds (core- or GPU-seconds) per sample at the target's cores per worker.
    pub device_seconds: Option<Spread>,
    pub hours: f64,
    /// Standard error of `hours`.
    pub hours_sem: f64,
    pub files: u64,
    pub bytes: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct TaskEstimate {
    pub tasks: u64,
    /// Samples of the largest task.
    pub samples: u64,
    pub workers: usize,
    /// Cores (CPU) or GPUs a task has.
    pub units: f64,
    /// Projected wall seconds of the largest task, and their standard error.
    pub wall_s: f64,
    pub wall_s_sem: f64,
    /// Device hours of the largest task.
    pub hours: f64,
    /// Fixed wall seconds each task pays once (included in `wall_s`).
    pub fixed_s: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct Estimate {
    pub recipe: String,
    pub width: u32,
    pub height: u32,
    pub samples_per_pixel: u32,
    /// The render keys categories set for themselves (measured like the rest: the sampled
    /// scenes render with them), by category.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub category_render: Vec<(String, String)>,
    pub seed: u64,
    pub start: u64,
    pub count: u64,
    pub device: String,
    /// `core-hours` or `GPU-hours`.
    pub unit: String,
    pub measured: Measurement,
    /// Measured wall seconds per sample here, over every category.
    pub seconds: Spread,
    pub categories: Vec<CategoryEstimate>,
    /// Device hours of the samples, of the tasks' fixed time, and their sum.
    pub sample_hours: f64,
    pub fixed_hours: f64,
    pub hours: f64,
    pub hours_sem: f64,
    pub files: u64,
    pub bytes: u64,
    pub task: TaskEstimate,
    /// Set by `farm --estimate` when no --time-limit was given: seconds, and how.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_limit_s: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_limit_rule: Option<String>,
}

/// Where the projection goes: how many tasks, and the workers and cores (or GPUs) of each.
#[derive(Debug, Clone, Copy)]
pub struct Target {
    pub tasks: u64,
    pub workers: usize,
    /// Cores (CPU) or GPUs of a task.
    pub units: f64,
}

impl Target {
    /// A run like the measured one: its workers, with the cores they had here.
    pub fn like(m: &Measurement, tasks: u64) -> Self {
        Self {
            tasks,
            workers: m.workers,
            units: m.units_per_worker * m.workers as f64,
        }
    }
}

/// Samples per category in `start..start+count` (exactly, up to [`EXACT_COUNT_LIMIT`]).
fn category_counts(recipe: &Recipe, seed: u64, start: u64, count: u64) -> Vec<u64> {
    if count <= EXACT_COUNT_LIMIT {
        let mut n: BTreeMap<&str, u64> = BTreeMap::new();
        for i in start..start + count {
            *n.entry(scene_category(recipe, seed, i).name.as_str())
                .or_default() += 1;
        }
        recipe
            .categories
            .iter()
            .map(|c| n.get(c.name.as_str()).copied().unwrap_or(0))
            .collect()
    } else {
        let total: f64 = recipe.categories.iter().map(|c| c.weight).sum();
        recipe
            .categories
            .iter()
            .map(|c| (c.weight / total * count as f64).round() as u64)
            .collect()
    }
}

/// How a measured sample's time carries over to a worker of the target: the renders' share scales
/// with the worker's cores (CPU; a GPU's renders do not), the rest of the sample stays serial.
struct WorkerScale {
    /// Cores (CPU) or GPUs of one worker of the target.
    per_worker: f64,
    /// Factor on the render seconds.
    render: f64,
}

impl WorkerScale {
    fn new(m: &Measurement, target: Target) -> Self {
        let per_worker = target.units / target.workers.max(1) as f64;
        let render = match m.device {
            Device::Cpu => m.units_per_worker / per_worker,
            Device::Gpu => 1.0,
        };
        Self { per_worker, render }
    }

    /// Wall seconds of the sample on a worker of the target.
    fn wall(&self, s: &SampleCost) -> f64 {
        (s.seconds - s.parallel_seconds) + s.parallel_seconds * self.render
    }

    /// Its device seconds there (core- or GPU-seconds).
    fn device_seconds(&self, s: &SampleCost) -> f64 {
        self.wall(s) * self.per_worker
    }
}

/// The measured samples of one category.
fn measured_in<'a>(m: &'a Measurement, category: &str) -> Vec<&'a SampleCost> {
    m.samples
        .iter()
        .filter(|s| s.category == category)
        .collect()
}

/// The relative spread of a sample's device seconds, pooled over the categories measured twice
/// or more (it stands in for a category measured once); with no category measured twice, the
/// spread over all samples (categories mixed: larger).
fn pooled_relative_spread(m: &Measurement, recipe: &Recipe, scale: &WorkerScale) -> Option<f64> {
    let (mut sum, mut degrees) = (0.0, 0.0);
    for c in &recipe.categories {
        let v: Vec<f64> = measured_in(m, &c.name)
            .into_iter()
            .map(|s| scale.device_seconds(s))
            .collect();
        if v.len() > 1 {
            let sp = Spread::of(&v);
            let var = v.iter().map(|x| (x - sp.mean).powi(2)).sum::<f64>();
            sum += var / (sp.mean * sp.mean);
            degrees += (v.len() - 1) as f64;
        }
    }
    if degrees > 0.0 {
        Some((sum / degrees).sqrt())
    } else {
        let all: Vec<f64> = m.samples.iter().map(|s| scale.device_seconds(s)).collect();
        let sp = Spread::of(&all);
        sp.sem.map(|sem| sem * (all.len() as f64).sqrt() / sp.mean)
    }
}

/// One category's share of the run, with the sums the run's totals add up.
struct CategoryShare {
    estimate: CategoryEstimate,
    /// Device seconds of its samples, and their standard error.
    device_s: f64,
    device_s_sem: f64,
    /// Bytes of its manifest lines.
    manifest_bytes: f64,
}

/// Projects `samples` samples of `category`; a category nobody measured takes every measured
/// sample's costs.
fn category_share(
    m: &Measurement,
    category: &CategoryRecipe,
    samples: u64,
    scale: &WorkerScale,
    pooled: Option<f64>,
) -> CategoryShare {
    let mean = |v: &[u64]| v.iter().sum::<u64>() as f64 / v.len().max(1) as f64;
    let measured = measured_in(m, &category.name);
    let pick: Vec<&SampleCost> = if measured.is_empty() {
        m.samples.iter().collect()
    } else {
        measured.clone()
    };
    let ds: Vec<f64> = pick.iter().map(|s| scale.device_seconds(s)).collect();
    let sp = Spread::of(&ds);
    let sem = sp
        .sem
        .or_else(|| pooled.map(|cv| cv * sp.mean / (ds.len() as f64).sqrt()))
        .unwrap_or(0.0);
    let f = mean(&pick.iter().map(|s| s.files).collect::<Vec<_>>());
    let b = mean(&pick.iter().map(|s| s.bytes).collect::<Vec<_>>());
    let mb = mean(&pick.iter().map(|s| s.manifest_bytes).collect::<Vec<_>>());
    let nf = samples as f64;
    CategoryShare {
        estimate: CategoryEstimate {
            name: category.name.clone(),
            weight: category.weight,
            samples,
            measured: measured.len(),
            seconds: (!measured.is_empty())
                .then(|| Spread::of(&measured.iter().map(|s| s.seconds).collect::<Vec<_>>())),
            device_seconds: (!measured.is_empty()).then_some(sp),
            hours: nf * sp.mean / 3600.0,
            hours_sem: nf * sem / 3600.0,
            files: (nf * f).round() as u64,
            bytes: (nf * (b + mb)).round() as u64,
        },
        device_s: nf * sp.mean,
        device_s_sem: nf * sem,
        manifest_bytes: nf * mb,
    }
}

/// Projects a measurement onto `count` samples from `start` run as `target`.
pub fn project(
    m: &Measurement,
    recipe: &Recipe,
    seed: u64,
    start: u64,
    count: u64,
    target: Target,
) -> Estimate {
    let scale = WorkerScale::new(m, target);
    let pooled = pooled_relative_spread(m, recipe, &scale);
    let counts = category_counts(recipe, seed, start, count);
    let shares: Vec<CategoryShare> = recipe
        .categories
        .iter()
        .zip(&counts)
        .map(|(c, &n)| category_share(m, c, n, &scale, pooled))
        .collect();
    let (mut sample_ds, mut var_ds, mut files, mut bytes) = (0.0, 0.0, 0u64, 0u64);
    let mut manifest_bytes = 0.0;
    for s in &shares {
        sample_ds += s.device_s;
        var_ds += s.device_s_sem.powi(2);
        manifest_bytes += s.manifest_bytes;
        files += s.estimate.files;
        bytes += s.estimate.bytes;
    }
    // Per task: dataset.json and its manifest; more than one task: the merged manifest too.
    files += target.tasks * m.dataset_files;
    bytes += target.tasks * m.dataset_bytes;
    if target.tasks > 1 {
        files += 1;
        bytes += manifest_bytes.round() as u64;
    }
    let fixed_hours = target.tasks as f64 * m.task_fixed_s * target.units / 3600.0;
    let task_samples = count.div_ceil(target.tasks);
    let per_sample_wall = sample_ds / count as f64 / scale.per_worker;
    let per_sample_wall_sem = var_ds.sqrt() / count as f64 / scale.per_worker;
    let workers = target.workers.max(1) as f64;
    let task_wall = m.task_fixed_s + task_samples as f64 * per_sample_wall / workers;
    let task = TaskEstimate {
        tasks: target.tasks,
        samples: task_samples,
        workers: target.workers,
        units: target.units,
        wall_s: task_wall,
        wall_s_sem: task_samples as f64 * per_sample_wall_sem / workers,
        hours: task_wall * target.units / 3600.0,
        fixed_s: m.task_fixed_s,
    };
    Estimate {
        recipe: recipe.name.clone(),
        width: recipe.camera.width,
        height: recipe.camera.height,
        samples_per_pixel: recipe.render.samples,
        category_render: recipe
            .categories
            .iter()
            .filter_map(|c| {
                let keys = serde_json::to_string(c.render.as_ref()?).ok()?;
                Some((c.name.clone(), keys))
            })
            .collect(),
        seed,
        start,
        count,
        device: m.device.to_string(),
        unit: match m.device {
            Device::Cpu => "core-hours",
            Device::Gpu => "GPU-hours",
        }
        .into(),
        seconds: Spread::of(&m.samples.iter().map(|s| s.seconds).collect::<Vec<_>>()),
        measured: m.clone(),
        categories: shares.into_iter().map(|s| s.estimate).collect(),
        sample_hours: sample_ds / 3600.0,
        fixed_hours,
        hours: sample_ds / 3600.0 + fixed_hours,
        hours_sem: var_ds.sqrt() / 3600.0,
        files,
        bytes,
        task,
        time_limit_s: None,
        time_limit_rule: None,
    }
}

impl Estimate {
    /// The time limit of a task from this estimate: [`TIME_LIMIT_SAFETY`] × the largest task's
    /// projected wall time, plus `grace_s`, rounded up to [`TIME_LIMIT_STEP_S`].
    pub fn time_limit(&self, grace_s: u64) -> TimeLimit {
        TimeLimit::round_up(
            TIME_LIMIT_SAFETY * self.task.wall_s + grace_s as f64,
            TIME_LIMIT_STEP_S,
        )
    }

    pub fn set_time_limit(&mut self, grace_s: u64) -> TimeLimit {
        let t = self.time_limit(grace_s);
        self.time_limit_s = Some(t.seconds());
        self.time_limit_rule = Some(format!(
            "{TIME_LIMIT_SAFETY} × the largest task's projected {:.0} s + {grace_s} s grace, rounded up to {} min",
            self.task.wall_s,
            TIME_LIMIT_STEP_S / 60
        ));
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(index: u64, category: &str, seconds: f64) -> SampleCost {
        SampleCost {
            index,
            category: category.into(),
            seconds,
            parallel_seconds: seconds - 2.0,
            files: 5,
            bytes: 1000,
            manifest_bytes: 100,
        }
    }

    fn measurement(samples: Vec<SampleCost>) -> Measurement {
        Measurement {
            samples,
            worker_start_s: vec![5.0],
            task_fixed_s: 30.0,
            workers: 1,
            threads: 2,
            units_per_worker: 2.0,
            device: Device::Cpu,
            machine: "test".into(),
            worker_restarts: 0,
            failed: 0,
            dataset_files: 2,
            dataset_bytes: 400,
        }
    }

    #[test]
    fn renders_scale_with_cores_and_the_serial_rest_does_not() {
        let recipe = Recipe::preset("crestereo").unwrap();
        let names: Vec<&str> = recipe.categories.iter().map(|c| c.name.as_str()).collect();
        // 10 s a sample here on 2 cores, 8 of them in the renders: 2 + 8 × 2/4 = 6 s on 4 cores.
        let m = measurement(
            names
                .iter()
                .enumerate()
                .map(|(i, n)| sample(i as u64, n, 10.0))
                .collect(),
        );
        let target = Target {
            tasks: 2,
            workers: 1,
            units: 4.0,
        };
        let mut e = project(&m, &recipe, 7, 0, 1000, target);
        let counts: u64 = e.categories.iter().map(|c| c.samples).sum();
        assert_eq!(counts, 1000, "the range's exact counts add up");
        assert!((e.sample_hours - 1000.0 * 6.0 * 4.0 / 3600.0).abs() < 1e-9);
        assert!((e.fixed_hours - 2.0 * 30.0 * 4.0 / 3600.0).abs() < 1e-12);
        assert_eq!(e.task.samples, 500);
        assert!((e.task.wall_s - (30.0 + 500.0 * 6.0)).abs() < 1e-9);
        assert_eq!(e.hours_sem, 0.0, "equal samples: no spread");
        // Five files a sample, dataset.json and a manifest per task, and the merged manifest.
        assert_eq!(e.files, 1000 * 5 + 2 * 2 + 1);
        assert_eq!(e.bytes, 1000 * 1100 + 2 * 400 + 1000 * 100);
        // 1.5 × 3030 s + 120 s = 4665 s, rounded up to 5 minutes.
        assert_eq!(e.set_time_limit(120).seconds(), 4800);
        assert!(
            e.text().contains("time limit per task: 01:20:00"),
            "{}",
            e.text()
        );
    }

    #[test]
    fn a_category_measured_once_borrows_the_pooled_spread() {
        let recipe = Recipe::preset("crestereo").unwrap();
        let (a, b) = (&recipe.categories[0].name, &recipe.categories[1].name);
        let m = measurement(vec![
            sample(0, a, 10.0),
            sample(1, a, 14.0),
            sample(2, b, 12.0),
        ]);
        let e = project(&m, &recipe, 7, 0, 1000, Target::like(&m, 1));
        let (ca, cb) = (&e.categories[0], &e.categories[1]);
        let sa = ca.device_seconds.unwrap();
        let cv = sa.sem.unwrap() * 2f64.sqrt() / sa.mean;
        let sb = cb.device_seconds.unwrap();
        assert_eq!(sb.sem, None, "one value has no spread of its own");
        let want = cb.samples as f64 * cv * sb.mean / 3600.0;
        assert!(
            (cb.hours_sem - want).abs() < 1e-12,
            "{} vs {want}",
            cb.hours_sem
        );
        // Categories not measured at all are projected from every measured sample.
        assert_eq!(e.categories[2].measured, 0);
        assert!(e.categories[2].seconds.is_none() && e.categories[2].hours > 0.0);
    }
}
