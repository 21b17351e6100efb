//! Running a command in a test: both streams as one text, success or failure asserted with
//! what the command said.

/// A finished command's stdout then stderr, as one text (what a person at the terminal saw).
pub fn output_text(o: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Runs `c` with no standard input and asserts that it succeeded, showing both streams if not.
pub fn run_ok(c: &mut std::process::Command) -> std::process::Output {
    let o = c
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {c:?}: {e}"));
    assert!(o.status.success(), "{c:?} failed:\n{}", output_text(&o));
    o
}

/// Runs `c` with no standard input, asserts that it failed, and returns what it said.
pub fn run_fails(c: &mut std::process::Command) -> String {
    let o = c
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {c:?}: {e}"));
    let text = output_text(&o);
    assert!(!o.status.success(), "{c:?} succeeded:\n{text}");
    text
}

/// Runs `c` with no standard input, whatever its exit, prints what it said (a failing test then
/// shows it) and returns its output with that text.
pub fn run_shown(c: &mut std::process::Command) -> (std::process::Output, String) {
    let o = c
        .stdin(std::process::Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {c:?}: {e}"));
    let text = output_text(&o);
    println!("{text}");
    (o, text)
}
