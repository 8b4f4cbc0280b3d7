//! `report.html`: one self-contained file a person can send — the validation table, the
//! uncertainty of the fit and its coverage, explain's findings, the plots inline as SVG, the
//! provenance and the exact command. No external resource (no script, stylesheet, font or
//! image link); print CSS lays it out on A4.

use std::fmt::Write;
use std::path::Path;

use crate::report::plot::PlotError;
use crate::validate::{Coverage, ValidationReport};

/// Everything the report shows.
#[derive(Debug, Clone, Default)]
pub struct ReportContent {
    /// Title.
    pub title: String,
    /// The exact command that wrote the report.
    pub command: String,
    /// Provenance: (what, value) — files with their size and CRC-32, model id, tool version.
    pub provenance: Vec<(String, String)>,
    /// The comparison table as printed (no model / static / adaptive).
    pub table: String,
    /// Coverage of the fit's prediction interval, if the fit report was given.
    pub coverage: Option<Coverage>,
    /// The fit's uncertainty, one line each (prediction interval, VIF warnings, held-out).
    pub uncertainty: Vec<String>,
    /// explain's findings, one line each, and its full text.
    pub explain: Option<(Vec<String>, String)>,
    /// Why explain was not run, when [`ReportContent::explain`] is `None`.
    pub explain_absent: String,
    /// What the compensator itself said during the run, one line each (a campaign: its
    /// `MODEL_STALE` rises with their times); `None`: no device took part (no section).
    pub device: Option<Vec<String>>,
    /// Plots: (title, SVG text).
    pub plots: Vec<(String, String)>,
}

/// HTML-escapes text.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

const CSS: &str = "body{font-family:'DejaVu Sans','Liberation Sans',Arial,sans-serif;max-width:60rem;\
margin:1.5rem auto;padding:0 1rem;color:#111;line-height:1.4}\
h1{font-size:1.6rem}h2{font-size:1.2rem;border-bottom:1px solid #ccc;margin-top:1.6rem}\
pre{background:#f5f5f5;padding:.6rem;overflow-x:auto;font-size:.78rem;white-space:pre-wrap}\
table{border-collapse:collapse;font-size:.85rem}td,th{border:1px solid #ccc;padding:.2rem .5rem;text-align:left}\
figure{margin:1rem 0;page-break-inside:avoid;break-inside:avoid}figure svg{width:100%;height:auto}\
figcaption{font-size:.85rem;color:#444}.warn{color:#8a4b00}\
@page{size:A4;margin:15mm}\
@media print{body{max-width:none;margin:0;padding:0;font-size:10pt}pre{font-size:7pt}\
h2{page-break-after:avoid;break-after:avoid}}";

impl ReportContent {
    /// The HTML text.
    pub fn render(&self) -> String {
        let mut h = String::new();
        let _ = write!(
            h,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
             <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
             <title>{}</title><style>{CSS}</style></head><body>\n<h1>{}</h1>\n",
            escape(&self.title),
            escape(&self.title)
        );
        h += "<h2>Validation</h2>\n<pre>";
        h += &escape(&self.table);
        h += "</pre>\n";
        h += "<h2>Uncertainty</h2>\n<ul>\n";
        match &self.coverage {
            Some(c) => {
                let _ = writeln!(
                    h,
                    "<li>Coverage of the fit's {:.0} % prediction interval (static): <b>{:.1} %</b> of {} visit-axes inside (median half-width {:.1} nm).</li>",
                    100.0 * c.level,
                    100.0 * c.fraction(),
                    c.n,
                    c.median_half_width_um * 1e3
                );
            }
            None => h += "<li>No fit report given (<code>--fit-json</code>): no prediction interval, no coverage.</li>\n",
        }
        for l in &self.uncertainty {
            let class = if l.starts_with("warning") {
                " class=\"warn\""
            } else {
                ""
            };
            let _ = writeln!(h, "<li{class}>{}</li>", escape(l));
        }
        h += "</ul>\n";
        if let Some(lines) = &self.device {
            h += "<h2>What the compensator said</h2>\n<ul>\n";
            for l in lines {
                let class = if l.starts_with("MODEL_STALE") {
                    " class=\"warn\""
                } else {
                    ""
                };
                let _ = writeln!(h, "<li{class}>{}</li>", escape(l));
            }
            h += "</ul>\n";
        }
        h += "<h2>What the model left out (explain)</h2>\n";
        match &self.explain {
            Some((findings, text)) => {
                if findings.is_empty() {
                    h += "<p>explain found no effect to add.</p>\n";
                } else {
                    h += "<ul>\n";
                    for f in findings {
                        let _ = writeln!(h, "<li>{}</li>", escape(f));
                    }
                    h += "</ul>\n";
                }
                let _ = writeln!(h, "<pre>{}</pre>", escape(text));
            }
            None => {
                let _ = writeln!(h, "<p>Not run ({}).</p>", escape(&self.explain_absent));
            }
        }
        h += "<h2>Plots</h2>\n";
        for (title, svg) in &self.plots {
            let _ = writeln!(
                h,
                "<figure>{svg}<figcaption>{}</figcaption></figure>",
                escape(title)
            );
        }
        h += "<h2>Provenance</h2>\n<table>\n";
        for (k, v) in &self.provenance {
            let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(k), escape(v));
        }
        h += "</table>\n<h2>Command</h2>\n<pre>";
        h += &escape(&self.command);
        h += "</pre>\n</body></html>\n";
        h
    }
}

/// The report plots of `reports` as (title, SVG text), drawn by [`crate::report::write_report`]
/// into a scratch folder that is removed afterwards.
pub fn inline_plots(reports: &[&ValidationReport]) -> Result<Vec<(String, String)>, PlotError> {
    let dir = std::env::temp_dir().join(format!(
        "nanocal-report-html-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos())
    ));
    let files = crate::report::write_report(&dir, reports)?;
    let mut out = Vec::new();
    for f in files
        .iter()
        .filter(|f| f.extension().is_some_and(|e| e == "svg"))
    {
        let text = std::fs::read_to_string(f).map_err(|e| PlotError::Backend {
            path: f.clone(),
            message: e.to_string(),
        })?;
        // inline SVG needs no XML declaration
        let svg = match text.find("<svg") {
            Some(i) => text[i..].to_string(),
            None => text,
        };
        let title = f
            .file_stem()
            .map(|s| s.to_string_lossy().replace('_', " "))
            .unwrap_or_default();
        out.push((title, svg));
    }
    std::fs::remove_dir_all(&dir).ok();
    Ok(out)
}

/// `(size, CRC-32)` of a file, for the provenance table.
pub fn file_fingerprint(path: &Path) -> String {
    match std::fs::read(path) {
        Ok(b) => format!(
            "{} ({} bytes, CRC-32 {:08x})",
            path.display(),
            b.len(),
            nanocal_model::blob::crc32(&b)
        ),
        Err(e) => format!("{} (unreadable: {e})", path.display()),
    }
}

/// The command line as typed, each argument shell-quoted when it needs it.
pub fn command_line() -> String {
    std::env::args()
        .map(|a| {
            if !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@%".contains(c))
            {
                a
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}
