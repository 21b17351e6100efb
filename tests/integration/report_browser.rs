//! `stereogen report` on a dataset the real generator rendered (and audited), opened in a real
//! headless Chromium from a file:// URL with the network disabled: the page loads without
//! console errors, every gallery picture decodes, the charts are there, and a screenshot is left
//! in `target/tmp/report_browser/` for a person to look at. The page must also be well-formed
//! markup, and a damaged or empty dataset still gets a page that lists what is wrong.
//!
//! Chromium is looked for on PATH and, where missing, installed with apt-get (Debian's
//! `chromium`) when the test runs as root; without it the browser part is skipped with a note,
//! unless `CI` or `STEREOGEN_REQUIRE_BROWSER` is set (as `.ci/run` does): then it fails.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use test_support::{generate_tiny_dataset, run_shown, stereogen_cmd};

use stereogen::dataset::{DatasetLayout, Manifest};

const SCENES: u64 = 8;
const THUMBNAILS: usize = 6;

fn run(args: &[&str], paths: &[&Path]) -> (Output, String) {
    run_shown(stereogen_cmd(args).args(paths))
}

fn report(data: &Path, out: &Path, thumbnails: usize) -> String {
    let (o, text) = run(
        &[
            "report",
            "--thumbnails",
            &thumbnails.to_string(),
            "--out",
            &out.to_string_lossy(),
        ],
        &[data],
    );
    assert!(o.status.success(), "report failed: {text}");
    let html = std::fs::read_to_string(out).unwrap();
    // Well-formed markup (an XML parser accepts it), and nothing fetched from elsewhere.
    roxmltree::Document::parse_with_options(
        &html,
        roxmltree::ParsingOptions {
            allow_dtd: true,
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("{}: not well-formed: {e}", out.display()));
    // (The one URL allowed is the SVG namespace, a name rather than an address.)
    let without_namespace = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for needle in [
        "http:",
        "https:",
        "<script",
        "src=\"file:",
        "href=",
        "@import",
        "url(",
    ] {
        assert!(
            !without_namespace.contains(needle),
            "{} refers to {needle}",
            out.display()
        );
    }
    html
}

fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|p| {
        std::env::split_paths(&p)
            .map(|d| d.join(name))
            .find(|f| f.is_file())
    })
}

/// A Chromium executable, installing Debian's package when missing and allowed.
fn chromium() -> Option<PathBuf> {
    let find = || {
        ["chromium", "chromium-browser", "google-chrome"]
            .iter()
            .find_map(|n| which(n))
    };
    if let Some(c) = find() {
        return Some(c);
    }
    let root = unsafe { libc::geteuid() } == 0;
    if root && which("apt-get").is_some() {
        let _apt = test_support::turns::apt();
        if let Some(c) = find() {
            return Some(c); // installed while this test waited for its turn
        }
        eprintln!("report_browser: installing chromium with apt-get");
        let _ = Command::new("apt-get")
            .args(["install", "-y", "--no-install-recommends", "chromium"])
            .env("DEBIAN_FRONTEND", "noninteractive")
            .status();
    }
    find()
}

/// Chromium with no network: every host resolves to nothing and there is no proxy to reach.
fn headless(chromium: &Path) -> Command {
    let mut c = Command::new(chromium);
    c.args([
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--host-resolver-rules=MAP * ~NOTFOUND",
        "--proxy-server=127.0.0.1:9",
        "--virtual-time-budget=10000",
        "--enable-logging=stderr",
        "--v=0",
    ])
    .stdin(Stdio::null());
    c
}

/// What the browser found in the page, read by a harness page beside it that loads the report
/// in a frame (the report itself runs no script).
fn inspect(chromium: &Path, page: &Path) -> serde_json::Value {
    let harness = page.with_file_name("harness.html");
    let name = page.file_name().unwrap().to_string_lossy();
    std::fs::write(
        &harness,
        format!(
            r#"<!DOCTYPE html><html><body><iframe id="f" src="{name}" width="1280" height="900"></iframe><pre id="out">pending</pre><script>
const f = document.getElementById('f');
f.addEventListener('load', () => {{
  let r;
  try {{
    const d = f.contentDocument;
    const imgs = [...d.images];
    const gallery = [...d.querySelectorAll('.gallery-tile img')];
    r = {{ title: d.title, images: imgs.length, broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt),
          gallery_tiles: d.querySelectorAll('.gallery-tile').length, gallery_images: gallery.length,
          plots: d.querySelectorAll('svg.plot').length, plot_bars: d.querySelectorAll('svg.plot rect').length,
          sections: [...d.querySelectorAll('h2')].map(h => h.id) }};
  }} catch (e) {{ r = {{ error: String(e) }}; }}
  document.getElementById('out').textContent = 'RESULT ' + JSON.stringify(r);
}});
</script></body></html>"#
        ),
    )
    .unwrap();
    let o = headless(chromium)
        .arg("--allow-file-access-from-files")
        .arg("--dump-dom")
        .arg(format!("file://{}", harness.display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&o.stdout);
    let json = dom
        .split("RESULT ")
        .nth(1)
        .and_then(|s| s.split("</pre>").next())
        .unwrap_or_else(|| {
            panic!(
                "the harness did not report: {dom}\n{}",
                String::from_utf8_lossy(&o.stderr)
            )
        });
    serde_json::from_str(&json.replace("&quot;", "\"").replace("&amp;", "&")).unwrap()
}

/// Opens the report itself, screenshots it and returns the console messages of the page.
fn screenshot(chromium: &Path, page: &Path, png: &Path) -> Vec<String> {
    let o = headless(chromium)
        .arg("--window-size=1280,2600")
        .arg(format!("--screenshot={}", png.display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    assert!(
        png.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stderr)
        .lines()
        .filter(|l| l.contains("CONSOLE") || l.contains("Refused to"))
        .map(str::to_string)
        .collect()
}

fn out_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report_browser");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn report_of_a_generated_dataset_loads_in_a_real_browser() {
    let tmp = tempfile::tempdir().unwrap();
    let data = generate_tiny_dataset(tmp.path(), "data", SCENES, 3);
    let (o, text) = run(
        &[
            "audit",
            "--samples",
            "4",
            "--pixels",
            "1000",
            "--threads",
            "1",
        ],
        &[&data],
    );
    assert!(o.status.success(), "{text}");
    let dir = out_dir();
    let page = dir.join("report.html");
    let html = report(&data, &page, THUMBNAILS);
    for section in [
        "id=\"recipe\"",
        "id=\"counts\"",
        "id=\"timing\"",
        "id=\"distribution\"",
        "id=\"coverage\"",
        "id=\"audit\"",
        "id=\"gallery\"",
        "id=\"outliers\"",
    ] {
        assert!(html.contains(section), "no {section}");
    }
    let info: stereogen::dataset::DatasetInfo = DatasetLayout::new(&data).read_info().unwrap();
    assert!(
        html.contains(&info.recipe_fingerprint),
        "the recipe's fingerprint is shown"
    );
    assert!(
        html.contains("Verdict of <code>stereogen audit --check</code>"),
        "the audit's results are shown"
    );
    assert!(
        !html.contains("id=\"problems\""),
        "a sound dataset lists no problems"
    );
    assert!(html.len() < 2_000_000, "{} bytes", html.len());

    let Some(chromium) = chromium() else {
        assert!(
            std::env::var_os("CI").is_none()
                && std::env::var_os("STEREOGEN_REQUIRE_BROWSER").is_none(),
            "a browser is required here (CI or STEREOGEN_REQUIRE_BROWSER is set) but no chromium \
             is on PATH and apt-get could not install Debian's chromium package"
        );
        eprintln!(
            "report_browser: SKIPPED the browser checks: no chromium on PATH and none could be installed"
        );
        return;
    };
    let found = inspect(&chromium, &page);
    println!("browser: {found}");
    assert!(found.get("error").is_none(), "{found}");
    assert_eq!(found["gallery_tiles"], THUMBNAILS, "{found}");
    assert_eq!(
        found["gallery_images"],
        3 * THUMBNAILS,
        "left, disparity and right per sample: {found}"
    );
    assert_eq!(
        found["broken"].as_array().unwrap().len(),
        0,
        "pictures that did not decode: {found}"
    );
    // Object and pixel charts per category present plus overall (4 + 1) and the two coverage charts.
    assert!(found["plots"].as_u64().unwrap() >= 2 * 5 + 2, "{found}");
    assert!(found["plot_bars"].as_u64().unwrap() > 100, "{found}");
    let png = dir.join("report.png");
    let console = screenshot(&chromium, &page, &png);
    assert!(console.is_empty(), "console messages: {console:?}");
    let shot = image::open(&png).unwrap().to_rgb8();
    assert_eq!(shot.width(), 1280);
    // Not a blank page: the charts and thumbnails put many colours on it.
    let distinct: std::collections::HashSet<[u8; 3]> =
        shot.pixels().step_by(7).map(|p| p.0).collect();
    assert!(distinct.len() > 500, "{} colours", distinct.len());
    println!("report_browser: screenshot at {}", png.display());
}

#[test]
fn report_lists_what_is_wrong_and_renders_the_rest() {
    let tmp = tempfile::tempdir().unwrap();
    // A dataset whose only sample failed.
    let failed = test_support::generate_failed_dataset(tmp.path(), "failed");
    let html = report(&failed, &tmp.path().join("failed.html"), 4);
    assert!(
        html.contains("id=\"problems\"") && html.contains("no finished samples"),
        "{html}"
    );
    assert!(html.contains("Failed samples: 1."), "the failure is listed");

    // Two good samples, then one with an unreadable map and one without its scene.json.
    let data = generate_tiny_dataset(tmp.path(), "data", 3, 5);
    let layout = DatasetLayout::new(&data);
    let entries = Manifest::read(&layout.manifest()).unwrap();
    let exr = layout.abs(&entries[0].files.disp_left);
    std::fs::write(&exr, b"not an exr").unwrap();
    let scene = layout.abs(&entries[1].files.scene);
    std::fs::remove_file(&scene).unwrap();
    // And a run still writing: an unfinished last manifest line.
    std::fs::OpenOptions::new()
        .append(true)
        .open(layout.manifest())
        .and_then(|mut f| std::io::Write::write_all(&mut f, b"{\"id\":\"00000"))
        .unwrap();
    let html = report(&data, &tmp.path().join("damaged.html"), 3);
    let problems = html
        .split("id=\"problems\"")
        .nth(1)
        .expect("a problems section")
        .split("</div>")
        .next()
        .unwrap();
    assert!(
        problems.contains(&*exr.to_string_lossy()),
        "the unreadable map is named: {problems}"
    );
    assert!(
        problems.contains("scene.json"),
        "the missing scene.json is named: {problems}"
    );
    assert!(problems.contains("unfinished last line"), "{problems}");
    assert_eq!(
        html.matches("class=\"tile gallery-tile\"").count(),
        3,
        "every sample still gets its tile"
    );

    let (o, text) = run(&["report"], &[&tmp.path().join("nowhere")]);
    assert!(
        !o.status.success() && text.contains("nowhere") && text.lines().count() <= 2,
        "{text}"
    );
}
