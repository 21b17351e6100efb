//! How an [`Estimate`] reads as a table (what `stereogen estimate` and `farm --estimate` print).

use super::projection::{Estimate, Spread};
use crate::farm::TimeLimit;
use crate::render::Device;

impl Estimate {
    /// The estimate as a table: what was measured and where it is projected, a row per category,
    /// and the totals.
    pub fn text(&self) -> String {
        let mut out = self.header_lines();
        out.push(String::new());
        out.extend(self.table_lines());
        out.push(String::new());
        out.extend(self.summary_lines());
        out.join("\n") + "\n"
    }

    /// The recipe and range, the measurement and the target.
    fn header_lines(&self) -> Vec<String> {
        let m = &self.measured;
        let mut out = vec![format!(
            "estimate of {} samples of {} ({}×{} px, {} samples per pixel), seed {}, on the {}",
            self.count,
            self.recipe,
            self.width,
            self.height,
            self.samples_per_pixel,
            self.seed,
            self.device
        )];
        if !self.category_render.is_empty() {
            let own: Vec<String> = self
                .category_render
                .iter()
                .map(|(name, keys)| format!("{name} {keys}"))
                .collect();
            out.push(format!(
                "categories with their own render keys: {}",
                own.join(", ")
            ));
        }
        let mut measured = format!(
            "measured here: {} sample(s) with {} worker(s) × {} thread(s) on {}",
            m.samples.len(),
            m.workers,
            m.threads,
            m.machine
        );
        if m.failed > 0 {
            measured += &format!(", {} failed", m.failed);
        }
        if m.worker_restarts > 0 {
            measured += &format!(", {} worker restart(s)", m.worker_restarts);
        }
        out.push(measured);
        let starts: Vec<String> = m.worker_start_s.iter().map(|s| format!("{s:.1}")).collect();
        out.push(format!(
            "per task, once: {:.1} s wall (asset index, dataset, shutdown, and worker start-up, Blender import: {} s per worker)",
            m.task_fixed_s,
            starts.join(", ")
        ));
        let t = &self.task;
        let unit_word = match m.device {
            Device::Cpu => "core(s)",
            Device::Gpu => "GPU(s)",
        };
        out.push(format!(
            "projected to {} task(s) of {} worker(s) and {} {unit_word}",
            t.tasks,
            t.workers,
            fmt_units(t.units)
        ));
        out
    }

    /// A row per category, and the total.
    fn table_lines(&self) -> Vec<String> {
        let spread = |s: &Spread| format!("{:.1} / {:.1} / {:.1}", s.min, s.median, s.max);
        let hours = |h: f64, sem: f64| format!("{} ± {}", fmt_hours(h), fmt_hours(sem));
        let mut out = vec![table_row([
            "category",
            "weight",
            "samples",
            "n",
            "s/sample min/med/max",
            &self.unit,
            "output",
            "files",
        ])];
        for c in &self.categories {
            out.push(table_row([
                &c.name,
                &format!("{:.3}", c.weight),
                &c.samples.to_string(),
                &c.measured.to_string(),
                &c.seconds
                    .map_or("(not measured)".to_string(), |s| spread(&s)),
                &hours(c.hours, c.hours_sem),
                &fmt_bytes(c.bytes),
                &c.files.to_string(),
            ]));
        }
        out.push(table_row([
            "total",
            "",
            &self.count.to_string(),
            &self.measured.samples.len().to_string(),
            &spread(&self.seconds),
            &hours(self.hours, self.hours_sem),
            &fmt_bytes(self.bytes),
            &self.files.to_string(),
        ]));
        out
    }

    /// What the hours are made of, the largest task, its time limit, and how cores were scaled.
    fn summary_lines(&self) -> Vec<String> {
        let (m, t, unit) = (&self.measured, &self.task, &self.unit);
        let mut out = vec![
            format!(
                "{unit}: samples {} + per-task fixed time {}; ± is one standard error of the mean over the measured samples",
                fmt_hours(self.sample_hours),
                fmt_hours(self.fixed_hours)
            ),
            format!(
                "largest task: {} samples, {} ± {} wall ({} {unit})",
                t.samples,
                fmt_duration(t.wall_s),
                fmt_duration(t.wall_s_sem),
                fmt_hours(t.hours)
            ),
        ];
        if let (Some(l), Some(rule)) = (self.time_limit_s, &self.time_limit_rule) {
            out.push(format!(
                "time limit per task: {} ({rule})",
                TimeLimit(l).slurm()
            ));
        }
        let target_per_worker = t.units / t.workers.max(1) as f64;
        if m.device == Device::Cpu && (target_per_worker - m.units_per_worker).abs() > 1e-9 {
            out.push(format!(
                "cores per worker {} here, {} in the projection: the colour and depth renders scaled linearly, the rest of a sample not",
                fmt_units(m.units_per_worker),
                fmt_units(target_per_worker)
            ));
        }
        out
    }
}

/// One line of the table: the columns at their widths.
fn table_row(c: [&str; 8]) -> String {
    format!(
        "{:<12} {:>7} {:>9} {:>3}  {:<22} {:>18} {:>10} {:>11}",
        c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]
    )
}

fn fmt_units(u: f64) -> String {
    if (u - u.round()).abs() < 1e-9 {
        format!("{}", u.round() as u64)
    } else {
        format!("{u:.2}")
    }
}

fn fmt_hours(h: f64) -> String {
    if h >= 100.0 {
        format!("{h:.0}")
    } else if h >= 1.0 {
        format!("{h:.1}")
    } else {
        format!("{h:.3}")
    }
}

fn fmt_duration(s: f64) -> String {
    if s >= 3600.0 {
        format!("{:.1} h", s / 3600.0)
    } else if s >= 60.0 {
        format!("{:.1} min", s / 60.0)
    } else {
        format!("{s:.1} s")
    }
}

fn fmt_bytes(b: u64) -> String {
    let b = b as f64;
    for (unit, size) in [("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)] {
        if b >= size {
            return format!("{:.1} {unit}", b / size);
        }
    }
    format!("{b:.0} B")
}
