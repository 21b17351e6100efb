//! The AGCL ops on Flex: the Flex kernels and the composed ops against the historical
//! implementation (checks shared with the Vulkan tests in `agcl_checks`), the same checks with
//! the kernels switched off, and the scan for host reads in the network's sources.

use crate::agcl_checks;
use crestereo::{CpuAutodiffBackend, CpuBackend};

type B = CpuBackend;
type A = CpuAutodiffBackend;

#[test]
fn offset_corr_matches_reference() {
    agcl_checks::offset_corr_forward::<B>();
}

#[test]
fn warp_matches_reference() {
    agcl_checks::warp_forward::<B>();
}

#[test]
fn shift_corr_matches_reference() {
    agcl_checks::shift_corr_forward_and_gradients::<B, A>();
}

#[test]
fn gradients_match_autodiff_of_reference() {
    agcl_checks::offset_corr_and_warp_gradients::<A>();
}

#[test]
fn offset_corr_finite_difference_gradients() {
    agcl_checks::offset_corr_finite_differences::<B>();
}

#[test]
fn flex_has_agcl_kernels() {
    use burn::prelude::*;
    let device = Default::default();
    let t = |c| Tensor::<B, 4>::zeros([1, c, 4, 4], &device);
    let spec = crestereo::ops::agcl::CorrSpec::new(crestereo::SearchWindow::Row1x9, 1);
    assert_eq!(
        crestereo::ops::dispatch::kernels::<B>(&device),
        crestereo::ops::dispatch::Kernels::Flex
    );
    assert!(
        crestereo::ops::agcl::offset_corr_backward(t(4), t(4), t(2), t(18), t(9), spec).is_some()
    );
}

/// Host-read calls in Rust source: every host read in Burn goes through a method that returns
/// host data (`into_data`, `to_data`, `into_scalar`, then `into_vec`/`to_vec` on the result, or
/// `read*` on a device client). Comments are ignored; a line marked `// host read:` with a reason
/// is allowed (there is none in the network today). A file's unit-test module (from a top-level
/// `#[cfg(test)]` on, which by the crate's layout closes the file) is not network code and is not
/// scanned.
fn host_reads_in(text: &str) -> Vec<(usize, String)> {
    let reads = [
        ".into_data(",
        ".to_data(",
        ".into_scalar(",
        ".into_vec",
        ".to_vec(",
        "read_tensor",
        "read_async",
        ".read(",
    ];
    let mut found = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line == "#[cfg(test)]" {
            break;
        }
        let code = line.split("//").next().unwrap_or("");
        if line.contains("// host read:") {
            continue;
        }
        if reads.iter().any(|r| code.contains(r)) {
            found.push((i + 1, line.trim().to_string()));
        }
    }
    found
}

/// The files of `files` that are whole unit-test modules: declared `#[cfg(test)] mod NAME;` in
/// their parent (`a/b.rs` or `a/b/mod.rs` declares `a/b/NAME.rs` or `a/b/NAME/mod.rs`; `a/mod.rs`
/// declares `a/NAME.rs`). They are test code, as a file's own `#[cfg(test)]` tail is.
fn test_only_files(files: &[std::path::PathBuf]) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for parent in files {
        let text = std::fs::read_to_string(parent).unwrap();
        let lines: Vec<&str> = text.lines().map(str::trim).collect();
        let dir = if parent
            .file_name()
            .is_some_and(|n| n == "mod.rs" || n == "lib.rs")
        {
            parent.parent().unwrap().to_path_buf()
        } else {
            parent.with_extension("")
        };
        for pair in lines.windows(2) {
            let name = pair[1]
                .strip_prefix("mod ")
                .or_else(|| pair[1].strip_prefix("pub(crate) mod "))
                .and_then(|rest| rest.strip_suffix(';'));
            if let (true, Some(name)) = (pair[0] == "#[cfg(test)]", name) {
                out.push(dir.join(format!("{name}.rs")));
                out.push(dir.join(name).join("mod.rs"));
            }
        }
    }
    out
}

/// The forward and backward of the network read nothing back to the host: no source file under
/// `src/` that runs inside `forward` or `backward` contains a host read. Host I/O modules (image
/// and weight files, the inference driver's final read of its result) are listed and skipped;
/// any other file — including ones added later — is scanned, except whole unit-test modules.
#[test]
fn no_host_reads_in_forward_or_backward() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    // Host I/O by design: weights in and out, inference's image and disparity, the ONNX export.
    let host_io = ["infer.rs"];
    let mut files = Vec::new();
    let mut stack = vec![src.clone()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    assert!(
        files.len() >= 10,
        "sources not found under {}",
        src.display()
    );
    let test_only = test_only_files(&files);
    // The two unit-test files the crate has, and no network code among the skipped.
    for (rel, skipped) in [
        ("ops/conv2d/tests.rs", true),
        ("network/model/emit_tests.rs", true),
        ("network/refine.rs", false),
        ("network/model/mod.rs", false),
    ] {
        assert_eq!(test_only.contains(&src.join(rel)), skipped, "{rel}");
    }
    let mut offenders = Vec::new();
    for path in &files {
        let rel = path
            .strip_prefix(&src)
            .unwrap()
            .to_string_lossy()
            .to_string();
        if host_io.contains(&rel.as_str())
            || rel.starts_with("weights/")
            || rel.starts_with("export/")
            || test_only.contains(path)
        {
            continue;
        }
        for (line, code) in host_reads_in(&std::fs::read_to_string(path).unwrap()) {
            offenders.push(format!("{rel}:{line}: {code}"));
        }
    }
    assert!(
        offenders.is_empty(),
        "host reads in the network's forward/backward:\n{}",
        offenders.join("\n")
    );
}

/// The scan finds the reads of the sampler the fused op replaced (kept above as the reference).
#[test]
fn host_read_scan_detects_the_replaced_sampler() {
    let this_file = include_str!("../../../test-support/src/agcl_checks.rs");
    let start = this_file.find("fn reference_sample_points").unwrap();
    let end = this_file.find("fn pixel_grid").unwrap();
    let found = host_reads_in(&this_file[start..end]);
    // Two reads (x and y coordinates); rustfmt may split each `.into_data().into_vec()` chain
    // over two lines, so count the reads, not the lines.
    let reads = found
        .iter()
        .filter(|(_, code)| code.contains(".into_data("))
        .count();
    assert_eq!(reads, 2, "{found:?}");
}
