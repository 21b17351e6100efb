//! `stereogen setup`: the managed Blender environment, then the built-in content pack.

use std::path::PathBuf;

use stereogen::assets::pack::install_pack;
use stereogen::assets::stereogen_home;
use stereogen::render::{BlenderRuntime, Worker};

use super::RuntimeArgs;

/// The Python whose pip downloads the pack: the runtime's own when it is a Python, else the
/// `python3` on PATH (a Blender executable's bundled Python may lack pip).
fn pip_python(runtime: &BlenderRuntime) -> PathBuf {
    match runtime {
        BlenderRuntime::Python(p) => p.clone(),
        BlenderRuntime::Executable(_) => PathBuf::from("python3"),
    }
}

pub fn run(runtime: &RuntimeArgs, with_pack: bool) -> anyhow::Result<()> {
    let cfg = runtime.worker_options().resolve(1)?;
    let worker = Worker::spawn(&cfg)?;
    println!(
        "Blender {} (Python {}) ready via {}",
        worker.hello.blender,
        worker.hello.python,
        cfg.runtime.describe()
    );
    worker.shutdown();
    if with_pack {
        let index = install_pack(&stereogen_home(), &pip_python(&cfg.runtime))?;
        let photos = index.photos().len();
        let meshes = index.meshes().len();
        println!(
            "content pack {}: {photos} photo(s), {meshes} mesh(es) in {} (`stereogen assets list` shows them)",
            index.name,
            index.root.display()
        );
        for s in &index.skipped {
            println!("skipped: {}: {}", s.path.display(), s.reason);
        }
    }
    Ok(())
}
