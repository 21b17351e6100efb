//! Re-rendering a spec gives bit-identical disparity; a worker does not grow over many scenes.

use stereogen::assets::AssetIndex;
use stereogen::plan::{Recipe, plan_scene};
use stereogen::render::RenderService;
use test_support::{render, tiny_recipe, worker_config};

fn small_recipe() -> Recipe {
    let mut r = tiny_recipe("crestereo");
    r.camera.width = 96;
    r.camera.height = 72;
    r
}

#[test]
fn rendering_a_spec_twice_gives_identical_files() {
    let recipe = small_recipe();
    let spec = plan_scene(&recipe, &AssetIndex::default(), 3, 17);
    assert_eq!(
        spec.to_json(),
        plan_scene(&recipe, &AssetIndex::default(), 3, 17).to_json()
    );
    // Two separate worker processes.
    let a = render(&mut RenderService::new(worker_config()), &spec);
    let b = render(&mut RenderService::new(worker_config()), &spec);
    // Cycles on the CPU is deterministic for a fixed seed, so the colour images repeat too.
    for key in ["disp_left", "disp_right", "scene", "left", "right"] {
        assert_eq!(
            a.entry.sha256[key], b.entry.sha256[key],
            "{key} differs between renders"
        );
    }
    assert_eq!(a.left, b.left);
}

#[test]
fn worker_memory_is_flat_over_twenty_scenes() {
    let recipe = small_recipe();
    let mut service = RenderService::new(worker_config());
    let mut rss = Vec::new();
    // Four passes over the same five scenes: memory may follow what a scene holds, but a leak
    // shows as growth between the same point of successive passes.
    for index in (0..20).map(|i| i % 5) {
        let spec = plan_scene(&recipe, &AssetIndex::default(), 11, index);
        let rendered = service.render(&spec, |_| None).expect("render");
        rss.push(
            rendered.reply.report.rss_bytes.expect("worker reports RSS") as f64 / (1024.0 * 1024.0),
        );
    }
    let growth = rss[19] - rss[0];
    println!(
        "worker RSS: after 1 scene {:.1} MiB, after 10 {:.1} MiB, after 20 {:.1} MiB (growth {growth:.1} MiB)",
        rss[0], rss[9], rss[19]
    );
    let late_growth = rss[19] - rss[9];
    assert!(
        late_growth < 24.0,
        "worker grew {late_growth:.1} MiB between passes 2 and 4: {rss:?}"
    );
    assert!(
        growth < 96.0,
        "worker grew {growth:.1} MiB over 20 scenes: {rss:?}"
    );
}
