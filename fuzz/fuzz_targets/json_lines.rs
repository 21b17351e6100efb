//! JSON-lines bytes through the manifest reader and both sidecar-log readers: records, or one
//! error line naming the file; every manifest path accepted stays inside the dataset.
#![no_main]

use std::path::Path;

use stereo_io::datasets::stereogen::{
    FailureRecord, SkippedAssetRecord, read_manifest_from, read_sidecar_from,
};
use stereogen_fuzz::{Limited, check};

#[global_allocator]
static ALLOC: Limited = Limited;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let path = Path::new("f.jsonl");
    if let Some(m) = check(read_manifest_from(bytes, path), "f.jsonl") {
        for e in &m.entries {
            for (_, rel) in e.files.all() {
                assert!(rel.is_relative(), "an absolute path accepted: {rel:?}");
                assert!(
                    rel.components()
                        .all(|c| matches!(c, std::path::Component::Normal(_))),
                    "a path leaving the dataset accepted: {rel:?}"
                );
            }
        }
    }
    check(read_sidecar_from::<FailureRecord>(bytes, path), "f.jsonl");
    check(
        read_sidecar_from::<SkippedAssetRecord>(bytes, path),
        "f.jsonl",
    );
});
