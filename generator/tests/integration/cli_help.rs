//! The help text documents every flag (and building this test makes cargo build the binary that
//! the end-to-end tests in the workspace root run).

use std::process::Command;

#[test]
fn generate_help_explains_every_flag() {
    let out = Command::new(env!("CARGO_BIN_EXE_stereogen"))
        .args(["generate", "--help"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    for flag in [
        "--recipe",
        "--out",
        "--count",
        "--seed",
        "--start",
        "--shard",
        "--workers",
        "--blender",
        "--device",
        "--threads",
        "--timeout",
        "--retries",
        "--no-progress",
    ] {
        // Every flag has a line of its own, followed by an explanation.
        let at = help
            .lines()
            .position(|l| l.trim_start().starts_with(flag))
            .unwrap_or_else(|| panic!("{flag} missing from help:\n{help}"));
        let explained = help
            .lines()
            .nth(at)
            .is_some_and(|l| l.trim_start().len() > flag.len() + 12)
            || help
                .lines()
                .nth(at + 1)
                .is_some_and(|l| !l.trim().is_empty() && !l.trim_start().starts_with('-'));
        assert!(explained, "{flag} has no explanation:\n{help}");
    }
    assert!(help.contains("resumes"), "{help}");
}

#[test]
fn bad_shard_is_rejected_by_the_parser() {
    let out = Command::new(env!("CARGO_BIN_EXE_stereogen"))
        .args([
            "generate", "--out", "/tmp/x", "--count", "1", "--shard", "4/4",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("need 0 <= K < N"));
}
