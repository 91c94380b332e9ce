//! Session report: gathers what a session wrote into a directory tree (run summaries,
//! datasets, calibrations, diagnoses, laser method tables, SVG plots) and renders ONE
//! report for a field engineer, as Markdown and optionally as self-contained HTML.
//!
//! Every JSON file is read as a [`serde_json::Value`] so the report tolerates fields being
//! added to the formats; a file that does not parse is listed as a warning, never a panic.
//! Output is deterministic: files are visited in sorted path order and no clock is read.
//! Numbers are shown in the files' units (mm, degrees, seconds).

pub mod html;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::dataset::{read_dataset, Summary};

/// How deep below the report directory files are looked for.
const MAX_DEPTH: usize = 6;

/// One JSON file found in the session directory.
#[derive(Debug, Clone)]
pub struct Found {
    /// Path relative to the session directory (`/`-separated).
    pub rel: String,
    /// The parsed content.
    pub value: Value,
}

/// One dataset found in the session directory, with its `robocal inspect` summary.
#[derive(Debug, Clone)]
pub struct FoundDataset {
    /// Path relative to the session directory.
    pub rel: String,
    /// The summary.
    pub summary: Summary,
}

/// Everything gathered from a session directory, each list sorted by path.
#[derive(Debug, Clone, Default)]
pub struct Session {
    /// The session directory as given.
    pub dir: PathBuf,
    /// `summary.json` files of `robocal run`.
    pub runs: Vec<Found>,
    /// Datasets (`*.jsonl` that read as `robocal-dataset/1`).
    pub datasets: Vec<FoundDataset>,
    /// `calibration.json` files.
    pub calibrations: Vec<Found>,
    /// `diagnosis.json` files.
    pub diagnoses: Vec<Found>,
    /// `laser_report.json` files.
    pub laser_reports: Vec<Found>,
    /// SVG plots: relative path and content.
    pub plots: Vec<(String, String)>,
    /// Files that could not be read or parsed.
    pub warnings: Vec<String>,
}

fn walk(dir: &Path, depth: usize, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    entries.sort();
    for p in entries {
        let Ok(meta) = std::fs::symlink_metadata(&p) else {
            continue;
        };
        if meta.is_dir() {
            if depth < MAX_DEPTH {
                // Unreadable subdirectories are skipped, not fatal.
                let _ = walk(&p, depth + 1, out);
            }
        } else if meta.is_file() {
            out.push(p);
        }
    }
    Ok(())
}

fn rel_of(base: &Path, p: &Path) -> String {
    let r = p.strip_prefix(base).unwrap_or(p);
    r.components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("/")
}

fn read_json(p: &Path) -> Result<Value, String> {
    let text = std::fs::read_to_string(p).map_err(|e| e.to_string())?;
    serde_json::from_str(&text).map_err(|e| e.to_string())
}

/// Gathers the session files under `dir` (recursively, sorted by path).
pub fn gather(dir: &Path) -> anyhow::Result<Session> {
    let mut files = Vec::new();
    walk(dir, 0, &mut files)
        .map_err(|e| anyhow::anyhow!("reading directory {}: {e}", dir.display()))?;
    let mut s = Session {
        dir: dir.to_path_buf(),
        ..Session::default()
    };
    for p in files {
        let rel = rel_of(dir, &p);
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let slot = match name.as_str() {
            "summary.json" => Some(&mut s.runs),
            "calibration.json" => Some(&mut s.calibrations),
            "diagnosis.json" => Some(&mut s.diagnoses),
            "laser_report.json" => Some(&mut s.laser_reports),
            _ => None,
        };
        if let Some(slot) = slot {
            match read_json(&p) {
                Ok(value) if value.is_object() => slot.push(Found { rel, value }),
                Ok(_) => s
                    .warnings
                    .push(format!("{rel}: not a JSON object, ignored")),
                Err(e) => s.warnings.push(format!("{rel}: {e}")),
            }
        } else if name.ends_with(".jsonl") {
            match read_dataset(&p) {
                Ok(loaded) => {
                    let w = loaded.warnings.iter().map(ToString::to_string).collect();
                    s.datasets.push(FoundDataset {
                        rel,
                        summary: Summary::of(&loaded.dataset, w),
                    });
                }
                Err(e) => s.warnings.push(format!("{rel}: not a dataset ({e})")),
            }
        } else if name.ends_with(".svg") {
            match std::fs::read_to_string(&p) {
                Ok(t) => s.plots.push((rel, t)),
                Err(e) => s.warnings.push(format!("{rel}: {e}")),
            }
        }
    }
    // A `summary.json` that is not a run summary (no `planned`) is not reported as a run.
    s.runs.retain(|f| f.value.get("planned").is_some());
    Ok(s)
}

fn num(v: Option<&Value>) -> Option<f64> {
    v.and_then(Value::as_f64).filter(|x| x.is_finite())
}

fn f3(x: Option<f64>) -> String {
    x.map_or_else(|| "—".into(), |x| format!("{x:.3}"))
}

fn text(v: Option<&Value>) -> String {
    match v {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Null) | None => "—".into(),
        Some(other) => other.to_string(),
    }
}

/// Markdown table cell: no pipes or newlines.
fn cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

/// The held-out (or, failing that, cross-validated) error before and after, with its source.
#[derive(Debug, Clone, PartialEq)]
pub struct Headline {
    /// RMS before (mm).
    pub before_mm: Option<f64>,
    /// RMS after (mm).
    pub after_mm: Option<f64>,
    /// Where the two numbers come from.
    pub source: String,
    /// Effects found by the diagnosis (labels), sorted.
    pub effects: Vec<String>,
    /// Poses skipped during acquisition (None without a run summary).
    pub skipped: Option<usize>,
    /// Poses recorded during acquisition.
    pub recorded: Option<usize>,
}

impl Session {
    /// The numbers of the headline.
    pub fn headline(&self) -> Headline {
        let mut before = None;
        let mut after = None;
        let mut source = String::from("no held-out error in this directory");
        // 1. a diagnosis with held-out numbers: nominal -> final.
        for d in &self.diagnoses {
            let h = d.value.get("heldout_rms_mm");
            let b = num(h.and_then(|h| h.get("nominal")));
            let a = num(h.and_then(|h| h.get("final")));
            if b.is_some() && a.is_some() {
                before = b;
                after = a;
                source = format!("{} (held-out, nominal → final)", d.rel);
                break;
            }
        }
        // 2. a calibration's metrics.
        if before.is_none() {
            for c in &self.calibrations {
                let m = c.value.get("metrics");
                let b = num(m.and_then(|m| m.get("heldout_rms_mm_before")));
                let a = num(m.and_then(|m| m.get("heldout_rms_mm_after")));
                if b.is_some() && a.is_some() {
                    before = b;
                    after = a;
                    let how = text(m.and_then(|m| m.get("heldout_source")));
                    source = if how == "—" {
                        format!("{} (held-out)", c.rel)
                    } else {
                        format!("{} ({how})", c.rel)
                    };
                    break;
                }
            }
        }
        let mut effects: Vec<String> = self
            .diagnoses
            .iter()
            .flat_map(|d| {
                d.value
                    .get("chain")
                    .and_then(Value::as_array)
                    .cloned()
                    .unwrap_or_default()
            })
            .map(|c| {
                c.get("label")
                    .and_then(Value::as_str)
                    .map(str::to_string)
                    .unwrap_or_else(|| text(c.get("effect").and_then(|e| e.get("kind"))))
            })
            .collect();
        effects.sort();
        effects.dedup();
        let mut skipped = None;
        let mut recorded = None;
        for r in &self.runs {
            if let Some(n) = r.value.get("skipped").and_then(Value::as_array) {
                *skipped.get_or_insert(0) += n.len();
            }
            if let Some(n) = r.value.get("recorded").and_then(Value::as_u64) {
                *recorded.get_or_insert(0) += n as usize;
            }
        }
        Headline {
            before_mm: before,
            after_mm: after,
            source,
            effects,
            skipped,
            recorded,
        }
    }

    /// The one-line headline for a field engineer.
    pub fn headline_text(&self) -> String {
        let h = self.headline();
        let mut s = match (h.before_mm, h.after_mm) {
            (Some(b), Some(a)) => format!("held-out error {b:.3} mm → {a:.3} mm"),
            _ => "held-out error: not available".to_string(),
        };
        if self.diagnoses.is_empty() {
            s.push_str("; effects found: not diagnosed");
        } else if h.effects.is_empty() {
            s.push_str("; effects found: none");
        } else {
            let _ = write!(s, "; effects found: {}", h.effects.join(", "));
        }
        match h.skipped {
            Some(n) => {
                let _ = write!(s, "; {n} poses skipped");
            }
            None => s.push_str("; no acquisition summary"),
        }
        s
    }

    /// The whole report as one JSON value (for `--json`).
    pub fn to_json(&self) -> Value {
        let h = self.headline();
        json!({
            "format": "robocal-report/1",
            "headline": self.headline_text(),
            "heldout_rms_mm": { "before": h.before_mm, "after": h.after_mm, "source": h.source },
            "effects": h.effects,
            "poses_skipped": h.skipped,
            "poses_recorded": h.recorded,
            "runs": self.runs.iter().map(|f| json!({"file": f.rel, "summary": f.value})).collect::<Vec<_>>(),
            "datasets": self.datasets.iter().map(|d| json!({"file": d.rel, "summary": d.summary})).collect::<Vec<_>>(),
            "calibrations": self.calibrations.iter().map(|f| json!({"file": f.rel, "calibration": f.value})).collect::<Vec<_>>(),
            "diagnoses": self.diagnoses.iter().map(|f| json!({"file": f.rel, "diagnosis": f.value})).collect::<Vec<_>>(),
            "laser_reports": self.laser_reports.iter().map(|f| json!({"file": f.rel, "report": f.value})).collect::<Vec<_>>(),
            "plots": self.plots.iter().map(|(r, _)| r.clone()).collect::<Vec<_>>(),
            "warnings": self.warnings,
        })
    }

    /// The report as Markdown.
    pub fn markdown(&self) -> String {
        let mut m = String::new();
        let _ = writeln!(m, "# robocal session report\n");
        let _ = writeln!(m, "**{}**\n", self.headline_text());
        let h = self.headline();
        let _ = writeln!(m, "Held-out numbers from: {}.\n", h.source);
        if self.runs.is_empty()
            && self.datasets.is_empty()
            && self.calibrations.is_empty()
            && self.diagnoses.is_empty()
            && self.laser_reports.is_empty()
        {
            let _ = writeln!(m, "Nothing to report: no run summary, dataset, calibration, diagnosis or laser report found.\n");
        }
        for r in &self.runs {
            self.md_run(&mut m, r);
        }
        for d in &self.datasets {
            md_dataset(&mut m, d);
        }
        for c in &self.calibrations {
            md_calibration(&mut m, c);
        }
        for d in &self.diagnoses {
            md_diagnosis(&mut m, d);
        }
        for l in &self.laser_reports {
            md_laser(&mut m, l);
        }
        if !self.plots.is_empty() {
            let _ = writeln!(m, "## Plots\n");
            for (rel, _) in &self.plots {
                let _ = writeln!(m, "- `{rel}`");
            }
            m.push('\n');
        }
        if !self.warnings.is_empty() {
            let _ = writeln!(m, "## Warnings\n");
            for w in &self.warnings {
                let _ = writeln!(m, "- {}", cell(w));
            }
            m.push('\n');
        }
        m
    }

    fn md_run(&self, m: &mut String, r: &Found) {
        let v = &r.value;
        let _ = writeln!(m, "## Acquisition (`{}`)\n", r.rel);
        let _ = writeln!(
            m,
            "- poses planned {}, recorded {}, skipped {}, remaining {}",
            text(v.get("planned")),
            text(v.get("recorded")),
            v.get("skipped")
                .and_then(Value::as_array)
                .map_or(0, Vec::len),
            text(v.get("remaining"))
        );
        let _ = writeln!(
            m,
            "- poses/hour {}",
            num(v.get("poses_per_hour")).map_or("—".into(), |x| format!("{x:.0}"))
        );
        if let Some(t) = v.get("time").and_then(Value::as_object) {
            let parts: Vec<String> = t
                .iter()
                .map(|(k, x)| {
                    format!(
                        "{k} {}",
                        num(Some(x)).map_or("—".into(), |x| format!("{x:.1}"))
                    )
                })
                .collect();
            let _ = writeln!(m, "- time: {}", parts.join(", "));
        }
        if let Some(e) = v.get("events").and_then(Value::as_object) {
            let mut parts: Vec<String> = e
                .iter()
                .map(|(k, x)| format!("{k} {}", text(Some(x))))
                .collect();
            parts.sort();
            let _ = writeln!(
                m,
                "- events: {}",
                if parts.is_empty() {
                    "none".into()
                } else {
                    parts.join(", ")
                }
            );
        }
        match v.get("aborted") {
            Some(Value::Null) | None => {}
            Some(a) => {
                let _ = writeln!(m, "- **aborted**: {}", cell(&text(Some(a))));
            }
        }
        if let Some(sk) = v.get("skipped").and_then(Value::as_array) {
            if !sk.is_empty() {
                // Group skips by reason.
                let mut by: std::collections::BTreeMap<String, Vec<String>> = Default::default();
                for s in sk {
                    by.entry(text(s.get("reason")))
                        .or_default()
                        .push(text(s.get("id")));
                }
                let _ = writeln!(m, "\n| skip reason | poses | ids |\n|---|---:|---|");
                for (reason, ids) in by {
                    let _ = writeln!(
                        m,
                        "| {} | {} | {} |",
                        cell(&reason),
                        ids.len(),
                        ids.join(" ")
                    );
                }
            }
        }
        m.push('\n');
    }
}

fn md_dataset(m: &mut String, d: &FoundDataset) {
    let _ = writeln!(m, "## Dataset (`{}`)\n", d.rel);
    let _ = writeln!(m, "```text\n{}```\n", d.summary);
}

fn md_calibration(m: &mut String, c: &Found) {
    let v = &c.value;
    let _ = writeln!(
        m,
        "## Calibration `{}` (`{}`)\n",
        text(v.get("kind")),
        c.rel
    );
    if let Some(r) = v.get("robot") {
        let _ = writeln!(
            m,
            "- robot {} serial {}",
            text(r.get("model")),
            text(r.get("serial"))
        );
    }
    if let Some(met) = v.get("metrics").and_then(Value::as_object) {
        let _ = writeln!(m, "\n| metric | value |\n|---|---:|");
        for (k, x) in met {
            let s = match num(Some(x)) {
                Some(f) if x.is_f64() => format!("{f:.4}"),
                _ => text(Some(x)),
            };
            let _ = writeln!(m, "| {} | {} |", cell(k), cell(&s));
        }
    }
    if let Some(params) = v.get("params").and_then(Value::as_array) {
        let free: Vec<&Value> = params
            .iter()
            .filter(|p| p.get("free").and_then(Value::as_bool).unwrap_or(true))
            .collect();
        let fixed = params.len() - free.len();
        let _ = writeln!(
            m,
            "\n{} parameters ({} free, {} fixed):\n\n| parameter | value | std | unit | nominal |\n|---|---:|---:|---|---:|",
            params.len(),
            free.len(),
            fixed
        );
        for p in free {
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {} |",
                cell(&text(p.get("name"))),
                num(p.get("value")).map_or("—".into(), |x| format!("{x:.5}")),
                num(p.get("std")).map_or("—".into(), |x| format!("{x:.5}")),
                cell(&text(p.get("unit"))),
                num(p.get("nominal")).map_or("—".into(), |x| format!("{x:.5}")),
            );
        }
    }
    if let Some(effects) = v.get("effects").and_then(Value::as_array) {
        if effects.is_empty() {
            let _ = writeln!(m, "\nEffects: none.");
        } else {
            let _ = writeln!(m, "\nEffects:");
            for e in effects {
                let joint = e
                    .get("joint")
                    .map(|j| format!(" (joint {})", text(Some(j))));
                let _ = writeln!(
                    m,
                    "- {}{}: `{}`",
                    text(e.get("kind")),
                    joint.unwrap_or_default(),
                    cell(&e.get("params").map_or("{}".into(), Value::to_string))
                );
            }
        }
    }
    m.push('\n');
}

fn md_diagnosis(m: &mut String, d: &Found) {
    let v = &d.value;
    let _ = writeln!(m, "## Diagnosis (`{}`)\n", d.rel);
    let tr = v.get("train_rms_mm");
    let ho = v.get("heldout_rms_mm");
    let _ = writeln!(
        m,
        "| RMS (mm) | nominal | geometric | final |\n|---|---:|---:|---:|\n| train ({}) | {} | {} | {} |\n| held-out ({}) | {} | {} | {} |\n",
        text(v.get("n_train")),
        f3(num(tr.and_then(|t| t.get("nominal")))),
        f3(num(tr.and_then(|t| t.get("geometric")))),
        f3(num(tr.and_then(|t| t.get("final")))),
        text(v.get("n_heldout")),
        f3(num(ho.and_then(|t| t.get("nominal")))),
        f3(num(ho.and_then(|t| t.get("geometric")))),
        f3(num(ho.and_then(|t| t.get("final")))),
    );
    let chain = v
        .get("chain")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    if chain.is_empty() {
        let _ = writeln!(m, "No physical effect found beyond the geometric model.\n");
    } else {
        let _ = writeln!(
            m,
            "Chain (residual RMS → effect with evidence → new RMS):\n"
        );
        for (i, c) in chain.iter().enumerate() {
            let ev = c.get("evidence");
            let g = |k: &str| ev.and_then(|e| e.get(k));
            let _ = writeln!(
                m,
                "{}. train {} mm → **{}** (F {}, p {}, ΔBIC {}, CV gain {}) → {} mm; held-out {} → {} mm",
                i + 1,
                f3(num(c.get("train_rms_mm_before"))),
                cell(&text(c.get("label"))),
                num(g("F")).map_or("—".into(), |x| format!("{x:.1}")),
                num(g("p_value")).map_or("—".into(), |x| format!("{x:.2e}")),
                num(g("delta_bic")).map_or("—".into(), |x| format!("{x:.1}")),
                f3(num(g("cv_gain"))),
                f3(num(c.get("train_rms_mm_after"))),
                f3(num(c.get("heldout_rms_mm_before"))),
                f3(num(c.get("heldout_rms_mm_after"))),
            );
        }
        m.push('\n');
    }
    if v.get("nonparametric_used").and_then(Value::as_bool) == Some(true) {
        let _ = writeln!(m, "A nonparametric correction was added for structured residual no named effect explained.\n");
    }
    for (key, title) in [
        ("not_identifiable", "Not identifiable"),
        ("untestable", "Untestable"),
    ] {
        if let Some(list) = v.get(key).and_then(Value::as_array) {
            if !list.is_empty() {
                let _ = writeln!(m, "{title}:");
                for x in list {
                    let name = x.get("effect").or_else(|| x.get("candidate"));
                    match (name, x.get("reason")) {
                        (Some(n), Some(r)) => {
                            let _ = writeln!(m, "- {}: {}", text(Some(n)), cell(&text(Some(r))));
                        }
                        _ => {
                            let _ = writeln!(m, "- {}", cell(&text(Some(x))));
                        }
                    }
                }
                m.push('\n');
            }
        }
    }
}

fn md_laser(m: &mut String, l: &Found) {
    let v = &l.value;
    let _ = writeln!(m, "## Laser hand-eye methods (`{}`)\n", l.rel);
    let _ = writeln!(
        m,
        "| method | points | spread mm | FRE mm | TRE mm | RMS vs truth mm | note |\n|---|---:|---:|---:|---:|---:|---|"
    );
    for r in v
        .get("rows")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default()
    {
        let spread = match (num(r.get("spread_mean_mm")), num(r.get("spread_std_mm"))) {
            (Some(a), Some(s)) => format!("{a:.3} ± {s:.3}"),
            (Some(a), None) => format!("{a:.3}"),
            _ => "—".into(),
        };
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} | {} |",
            cell(&text(r.get("method"))),
            text(r.get("n_used")),
            spread,
            f3(num(r.get("fre_mm"))),
            f3(num(r.get("tre_mm"))),
            f3(num(r.get("spot_rms_vs_truth_mm"))),
            cell(&text(r.get("note"))),
        );
    }
    if let Some(x) = num(v.get("final_plane_rms_mm")) {
        let _ = writeln!(
            m,
            "\nFinal plane RMS {x:.4} mm ({}).",
            cell(&text(v.get("final_termination")))
        );
    }
    m.push('\n');
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Strips an XML declaration / doctype so an SVG file can be inlined in HTML.
fn inline_svg(svg: &str) -> Option<&str> {
    svg.find("<svg").map(|i| &svg[i..])
}

impl Session {
    /// The report as one self-contained HTML page: the Markdown text (pre-formatted) with
    /// every SVG plot inlined.
    pub fn html(&self) -> String {
        let mut h = String::new();
        h.push_str("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>robocal session report</title>\n");
        h.push_str("<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}pre{white-space:pre-wrap;font-size:13px}h1.headline{font-size:1.3em}figure{margin:1em 0}</style>\n</head><body>\n");
        let _ = writeln!(
            h,
            "<h1 class=\"headline\">{}</h1>",
            html_escape(&self.headline_text())
        );
        let _ = writeln!(h, "<pre>{}</pre>", html_escape(&self.markdown()));
        for (rel, svg) in &self.plots {
            match inline_svg(svg) {
                Some(s) => {
                    let _ = writeln!(
                        h,
                        "<figure>{s}<figcaption>{}</figcaption></figure>",
                        html_escape(rel)
                    );
                }
                None => {
                    let _ = writeln!(h, "<p>{}: not an SVG image</p>", html_escape(rel));
                }
            }
        }
        h.push_str("</body></html>\n");
        h
    }
}
