//! `validate --report report.html`: one self-contained file (plots inline as SVG, no external
//! resource), with the table, coverage, uncertainty, explain's findings, provenance and the
//! exact command; rendered by headless Chromium to a PNG and printed to an A4 PDF when a
//! browser is installed (Debian: `apt-get install chromium`), else that part skips with one
//! line.
use std::path::{Path, PathBuf};
use std::process::Command;

fn nanocal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nanocal"))
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn browser() -> Option<PathBuf> {
    for name in ["chromium", "chromium-browser", "google-chrome", "chrome"] {
        if let Ok(o) = Command::new("which").arg(name).output() {
            if o.status.success() {
                let p = String::from_utf8_lossy(&o.stdout).trim().to_string();
                if !p.is_empty() {
                    return Some(PathBuf::from(p));
                }
            }
        }
    }
    None
}

fn headless(browser: &Path, dir: &Path, args: &[String], html: &Path) -> std::process::Output {
    Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--allow-file-access-from-files",
        ])
        .arg(format!("--user-data-dir={}", dir.join("profile").display()))
        .args(args)
        .arg(format!("file://{}", html.display()))
        .output()
        .unwrap()
}

#[test]
fn validate_writes_a_self_contained_report_that_a_browser_renders_on_a4() {
    let dir = std::env::temp_dir().join(format!("nanocal-report-html-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (train, val) = nanocal::twin::examples::published_1dof(5);
    let tr = dir.join("training.csv");
    let va = dir.join("validation.csv");
    for (p, c) in [(&tr, train), (&va, val)] {
        nanocal::data::recording::Recording::from_columns(c.columns)
            .unwrap()
            .write_path(p)
            .unwrap();
    }
    let blob = dir.join("m.blob");
    let fit = dir.join("fit.json");
    run_ok(
        nanocal()
            .arg("fit")
            .arg(&tr)
            .arg("-o")
            .arg(&blob)
            .arg("--json")
            .arg(&fit),
    );
    let html_path = dir.join("report.html");
    run_ok(
        nanocal()
            .arg("validate")
            .arg(&blob)
            .arg(&va)
            .arg("--fit-json")
            .arg(&fit)
            .arg("--report")
            .arg(&html_path),
    );
    let html = std::fs::read_to_string(&html_path).unwrap();
    // self-contained: plots inline, nothing fetched from elsewhere
    assert!(html.matches("<svg").count() >= 5, "plots not inline");
    for external in ["src=\"http", "href=\"http", "<link", "<script", "<img"] {
        assert!(!html.contains(external), "external resource `{external}`");
    }
    // the content a person needs
    for needle in [
        "no model",
        "static",
        "adaptive KMZ",
        "Coverage of the fit's 95 % prediction interval (static)",
        "prediction interval of the correction over the training envelope",
        "held-out accuracy over 5 blocks of time",
        "What the model left out (explain)",
        "CRC-32",
        "model id",
        "@page{size:A4",
        "--fit-json",
    ] {
        assert!(html.contains(needle), "report lacks `{needle}`");
    }
    let Some(browser) = browser() else {
        eprintln!(
            "SKIPPED rendering report.html: no Chromium on this machine (Debian: apt-get install chromium)"
        );
        std::fs::remove_dir_all(&dir).ok();
        return;
    };
    let png = dir.join("report.png");
    let out = headless(
        &browser,
        &dir,
        &[
            format!("--screenshot={}", png.display()),
            "--window-size=1240,1754".into(),
        ],
        &html_path,
    );
    let bytes = std::fs::read(&png).unwrap_or_else(|_| {
        panic!(
            "Chromium wrote no PNG: {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    // IHDR: width and height as asked
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    assert_eq!((w, h), (1240, 1754));
    assert!(
        bytes.len() > 50_000,
        "a nearly blank page: {} bytes",
        bytes.len()
    );
    // printed: A4 pages (595 × 842 pt)
    let pdf = dir.join("report.pdf");
    let out = headless(
        &browser,
        &dir,
        &[
            format!("--print-to-pdf={}", pdf.display()),
            "--no-pdf-header-footer".into(),
        ],
        &html_path,
    );
    let pdf_bytes = std::fs::read(&pdf).unwrap_or_else(|_| {
        panic!(
            "Chromium wrote no PDF: {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let text = String::from_utf8_lossy(&pdf_bytes);
    // A4 is 595.3 × 841.9 pt; Chromium rounds the page to whole CSS pixels
    let i = text.find("/MediaBox [").expect("a MediaBox");
    let boxed: Vec<f64> = text[i + 11..]
        .split(']')
        .next()
        .unwrap()
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(
        (boxed[2] - 595.3).abs() < 1.0 && (boxed[3] - 841.9).abs() < 1.0,
        "not A4: {boxed:?}"
    );
    let pages = text.matches("/Type /Page\n").count() + text.matches("/Type /Page ").count();
    eprintln!(
        "report.html rendered: PNG {} bytes, PDF {} bytes, {pages} A4 pages",
        bytes.len(),
        pdf_bytes.len()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `demo` writes a `report.html` beside each stage's files (issue 19: `campaign` and `demo`
/// write the report `validate --report` does; the campaign's is checked in
/// `tests/campaign_stale.rs`): self-contained, with the stage's table, plots and files.
#[test]
fn demo_writes_a_self_contained_report_per_stage() {
    let dir = std::env::temp_dir().join(format!("nanocal-demo-html-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    run_ok(nanocal().arg("demo").arg("--out").arg(&dir));
    for (stage, files) in [
        (
            "1dof",
            &["validation.csv", "static.blob", "adaptive.blob"][..],
        ),
        ("2dof", &["validation.csv", "eq22.blob"][..]),
    ] {
        let html = std::fs::read_to_string(dir.join(stage).join("report.html"))
            .unwrap_or_else(|e| panic!("{stage}/report.html: {e}"));
        assert!(
            html.matches("<svg").count() >= 3,
            "{stage}: plots not inline"
        );
        for external in ["src=\"http", "href=\"http", "<link", "<script", "<img"] {
            assert!(!html.contains(external), "{stage}: external `{external}`");
        }
        for needle in ["no model", "static", "@page{size:A4", "CRC-32", "demo"] {
            assert!(html.contains(needle), "{stage}: report lacks `{needle}`");
        }
        for f in files {
            assert!(html.contains(f), "{stage}: provenance lacks {f}");
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}
