//! `stereogen render --spec`: one SceneSpec rendered into a dataset directory, as `generate`
//! would render it (checked before Blender starts, stoppable, scratch cleaned up).

use std::path::Path;

use stereogen::dataset::{DatasetLayout, finalize_sample};
use stereogen::interrupt::{self, Interrupted};
use stereogen::render::{RenderService, WorkerError, WorkerOptions, scratch};

pub fn run(spec: &Path, out: &Path, options: &WorkerOptions) -> anyhow::Result<()> {
    let spec = stereogen::dataset::scene_file::read_renderable_spec(spec)?;
    scratch::remove_orphans(&scratch::candidate_bases(Some(out)));
    let mut cfg = options.resolve(1)?;
    cfg.scratch = scratch::choose_base(
        Some(out),
        1,
        scratch::bytes_per_render(spec.rig.width, spec.rig.height),
    );
    cfg.stop = interrupt::install()?;
    let mut service = RenderService::new(cfg);
    let t0 = std::time::Instant::now();
    let rendered = match service.render(&spec, |_| None) {
        Err(WorkerError::Interrupted) => return Err(Interrupted::now().into()),
        other => other?,
    };
    let layout = DatasetLayout::new(out);
    let reply = &rendered.reply;
    let entry = finalize_sample(
        &layout,
        &spec,
        &reply.files,
        &reply.report.notes,
        t0.elapsed().as_secs_f64(),
        &reply.report.timings,
    )?;
    drop(rendered);
    let _ = std::fs::remove_dir(out.join(scratch::DATASET_SCRATCH_DIR));
    println!("{}", serde_json::to_string(&entry)?);
    Ok(())
}
