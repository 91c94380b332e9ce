//! Session report: gathers what a session wrote into a directory tree (run summaries,
//! datasets, calibrations, diagnoses, laser method tables, scan reports, pivots, SVG plots)
//! and renders ONE report for a field engineer, as Markdown and optionally as
//! self-contained HTML.
//!
//! Every output file is read through its typed schema ([`crate::schema`]), the same type
//! its writer serialises; a file that does not read (bad JSON, wrong or missing `format`
//! tag, wrong shape) is listed as a warning naming the file and the field, never a panic.
//! Output is deterministic: files are visited in sorted path order and no clock is read.
//! Numbers are shown in the files' units (mm, degrees, seconds).

pub mod html;
pub mod md_html;
pub mod sessions;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::dataset::{read_dataset, Summary};
use crate::schema::{
    self, CalibrationFile, DiagnosisFile, DiagnosisSensor, LaserReportFile, PivotFile,
    RunSummaryFile, ScanReportFile, SchemaFile,
};

/// How deep below the report directory files are looked for.
const MAX_DEPTH: usize = 6;

/// One output file found in the session directory, read through its schema type.
#[derive(Debug, Clone)]
pub struct Found<T> {
    /// Path relative to the session directory (`/`-separated).
    pub rel: String,
    /// The typed content.
    pub value: T,
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
    pub runs: Vec<Found<RunSummaryFile>>,
    /// Datasets (`*.jsonl` that read as `robocal-dataset/1`).
    pub datasets: Vec<FoundDataset>,
    /// `calibration.json` files.
    pub calibrations: Vec<Found<CalibrationFile>>,
    /// `diagnosis.json` files (every sensor).
    pub diagnoses: Vec<Found<DiagnosisFile>>,
    /// `laser_report.json` files.
    pub laser_reports: Vec<Found<LaserReportFile>>,
    /// `scan_report.json` files.
    pub scan_reports: Vec<Found<ScanReportFile>>,
    /// `pivot.json` files.
    pub pivots: Vec<Found<PivotFile>>,
    /// Navigation-chain and RCM files (`registration.json`, `robot_world.json`, `chain.json`,
    /// `rcm_report.json`): JSON objects shown by their scalar figures.
    pub navigation: Vec<Found<Value>>,
    /// `session.json` files of `robocal session` (JSON objects; the RCM session's held-out
    /// silhouette figures are read from their `measured` block).
    pub session_files: Vec<Found<Value>>,
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

fn take<T: SchemaFile>(p: &Path, rel: &str, slot: &mut Vec<Found<T>>, warnings: &mut Vec<String>) {
    let text = match crate::fsio::read_to_string(p) {
        Ok(t) => t,
        Err(e) => {
            warnings.push(format!("{rel}: {e}"));
            return;
        }
    };
    match schema::parse::<T>(&text, rel) {
        Ok(value) => slot.push(Found {
            rel: rel.to_string(),
            value,
        }),
        Err(e) => warnings.push(e.to_string()),
    }
}

/// A JSON object file (navigation chain, RCM report): kept as read; anything else is a warning.
fn take_json(p: &Path, rel: &str, slot: &mut Vec<Found<Value>>, warnings: &mut Vec<String>) {
    let parsed = crate::fsio::read_to_string(p)
        .map_err(|e| e.to_string())
        .and_then(|t| serde_json::from_str::<Value>(&t).map_err(|e| e.to_string()));
    match parsed {
        Ok(v) if v.is_object() => slot.push(Found {
            rel: rel.to_string(),
            value: v,
        }),
        Ok(_) => warnings.push(format!("{rel}: not a JSON object")),
        Err(e) => warnings.push(format!("{rel}: {e}")),
    }
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
        let w = &mut s.warnings;
        match name.as_str() {
            "summary.json" => take(&p, &rel, &mut s.runs, w),
            "session.json" => take_json(&p, &rel, &mut s.session_files, w),
            "calibration.json" => take(&p, &rel, &mut s.calibrations, w),
            "diagnosis.json" => take(&p, &rel, &mut s.diagnoses, w),
            "laser_report.json" => take(&p, &rel, &mut s.laser_reports, w),
            "scan_report.json" => take(&p, &rel, &mut s.scan_reports, w),
            "pivot.json" => take(&p, &rel, &mut s.pivots, w),
            "registration.json" | "robot_world.json" | "chain.json" | "rcm_report.json" => {
                take_json(&p, &rel, &mut s.navigation, w)
            }
            _ if name.ends_with(".jsonl") => match read_dataset(&p) {
                Ok(loaded) => {
                    let w = loaded.warnings.iter().map(ToString::to_string).collect();
                    s.datasets.push(FoundDataset {
                        rel,
                        summary: Summary::of(&loaded.dataset, w),
                    });
                }
                Err(e) => s.warnings.push(format!("{rel}: not a dataset ({e})")),
            },
            _ if name.ends_with(".svg") => match crate::fsio::read_to_string(&p) {
                Ok(t) => s.plots.push((rel, t)),
                Err(e) => s.warnings.push(format!("{rel}: {e}")),
            },
            _ => {}
        }
    }
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
    /// Camera: held-out reprojection RMS before / after the diagnosis (px), from a camera
    /// `diagnosis.json`.
    pub before_px: Option<f64>,
    pub after_px: Option<f64>,
    /// What the px figures measure: "reprojection" (camera) or "silhouette" (RCM endoscope).
    pub px_what: &'static str,
    /// Effects found by the diagnoses (labels, every sensor), sorted.
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
        // 1. a kinematic diagnosis with held-out numbers: nominal -> final.
        for d in &self.diagnoses {
            let h = &d.value.heldout_rms;
            let b = h.nominal_mm.or(h.base_model_mm);
            if let (Some(b), Some(a)) = (b, h.final_mm) {
                before = Some(b);
                after = Some(a);
                let stage = if h.nominal_mm.is_some() {
                    "nominal"
                } else {
                    "base model"
                };
                source = format!("{} (held-out, {stage} → final)", d.rel);
                break;
            }
        }
        // 2. a calibration's metrics.
        if before.is_none() {
            for c in &self.calibrations {
                let m = &c.value.metrics;
                let b = num(m.get("heldout_rms_mm_before"));
                let a = num(m.get("heldout_rms_mm_after"));
                if b.is_some() && a.is_some() {
                    before = b;
                    after = a;
                    let how = text(m.get("heldout_source"));
                    source = if how == "—" {
                        format!("{} (held-out)", c.rel)
                    } else {
                        format!("{} ({how})", c.rel)
                    };
                    break;
                }
            }
        }
        let (mut before_px, mut after_px) = (None, None);
        for d in &self.diagnoses {
            let h = &d.value.heldout_rms;
            if let (Some(b), Some(a)) = (h.base_model_px, h.final_px) {
                before_px = Some(b);
                after_px = Some(a);
                if before.is_none() {
                    source = format!("{} (held-out reprojection, calibration → final)", d.rel);
                }
                break;
            }
        }
        // 3. an RCM session: held-out silhouette RMS, seed 002 two-step → ML hand-eye.
        let mut px_what = "reprojection";
        if before.is_none() && before_px.is_none() {
            for f in &self.session_files {
                let m = f.value.get("measured");
                let b = num(m.and_then(|m| m.get("rcm_heldout_px_before")));
                let a = num(m.and_then(|m| m.get("rcm_heldout_px_after")));
                if let (Some(b), Some(a)) = (b, a) {
                    (before_px, after_px, px_what) = (Some(b), Some(a), "silhouette");
                    source = format!(
                        "{} (RCM held-out silhouette, seed 002 two-step → ML hand-eye)",
                        f.rel
                    );
                    break;
                }
            }
        }
        let mut effects: Vec<String> = self
            .diagnoses
            .iter()
            .flat_map(|d| d.value.effects.iter().map(|e| e.label.clone()))
            .collect();
        effects.sort();
        effects.dedup();
        let mut skipped = None;
        let mut recorded = None;
        for r in &self.runs {
            *skipped.get_or_insert(0) += r.value.summary.skipped.len();
            *recorded.get_or_insert(0) += r.value.summary.recorded;
        }
        Headline {
            before_mm: before,
            after_mm: after,
            source,
            before_px,
            after_px,
            px_what,
            effects,
            skipped,
            recorded,
        }
    }

    /// The one-line headline for a field engineer.
    pub fn headline_text(&self) -> String {
        let h = self.headline();
        let mut s = match (h.before_mm, h.after_mm, h.before_px, h.after_px) {
            (Some(b), Some(a), _, _) => format!("held-out error {b:.3} mm → {a:.3} mm"),
            (_, _, Some(b), Some(a)) => {
                format!("held-out {} error {b:.4} px → {a:.4} px", h.px_what)
            }
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
            "format": crate::schema::REPORT_FORMAT,
            "headline": self.headline_text(),
            "heldout_rms_mm": { "before": h.before_mm, "after": h.after_mm, "source": h.source },
            "heldout_rms_px": { "before": h.before_px, "after": h.after_px },
            "effects": h.effects,
            "poses_skipped": h.skipped,
            "poses_recorded": h.recorded,
            "runs": self.runs.iter().map(|f| json!({"file": f.rel, "summary": f.value})).collect::<Vec<_>>(),
            "datasets": self.datasets.iter().map(|d| json!({"file": d.rel, "summary": d.summary})).collect::<Vec<_>>(),
            "calibrations": self.calibrations.iter().map(|f| json!({"file": f.rel, "calibration": f.value})).collect::<Vec<_>>(),
            "diagnoses": self.diagnoses.iter().map(|f| json!({"file": f.rel, "diagnosis": f.value})).collect::<Vec<_>>(),
            "laser_reports": self.laser_reports.iter().map(|f| json!({"file": f.rel, "report": f.value})).collect::<Vec<_>>(),
            "scan_reports": self.scan_reports.iter().map(|f| json!({"file": f.rel, "report": f.value})).collect::<Vec<_>>(),
            "pivots": self.pivots.iter().map(|f| json!({"file": f.rel, "pivot": f.value})).collect::<Vec<_>>(),
            "navigation": self.navigation.iter().map(|f| json!({"file": f.rel, "content": f.value})).collect::<Vec<_>>(),
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
            && self.scan_reports.is_empty()
            && self.pivots.is_empty()
            && self.navigation.is_empty()
        {
            let _ = writeln!(m, "Nothing to report: no run summary, dataset, calibration, diagnosis, laser, scan or pivot report found.\n");
        }
        for r in &self.runs {
            md_run(&mut m, r);
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
        for s in &self.scan_reports {
            md_scan(&mut m, s);
        }
        for p in &self.pivots {
            md_pivot(&mut m, p);
        }
        for f in &self.navigation {
            md_navigation(&mut m, f);
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
}

/// A navigation-chain / RCM file: its format and every top-level scalar figure (numbers to
/// 4 decimals, strings, flags); nested tables are in the file (and in `--json`).
fn md_navigation(m: &mut String, f: &Found<Value>) {
    let title = match f.rel.rsplit('/').next().unwrap_or("") {
        "registration.json" => "CT ↔ tracker registration",
        "robot_world.json" => "Tracker ↔ robot base",
        "chain.json" => "Navigation chain (CT target → tool tip)",
        _ => "RCM endoscope hand-eye",
    };
    let _ = writeln!(m, "## {title} (`{}`)\n", f.rel);
    if let Some(o) = f.value.as_object() {
        for (k, v) in o {
            let shown = match v {
                Value::Number(n) => n
                    .as_f64()
                    .map_or_else(|| n.to_string(), |x| format!("{x:.4}")),
                Value::String(t) => cell(t),
                Value::Bool(b) => b.to_string(),
                _ => continue,
            };
            let _ = writeln!(m, "- {}: {shown}", cell(k));
        }
    }
    m.push('\n');
}

fn md_run(m: &mut String, r: &Found<RunSummaryFile>) {
    let v = &r.value.summary;
    let _ = writeln!(m, "## Acquisition (`{}`)\n", r.rel);
    let _ = writeln!(
        m,
        "- poses planned {}, recorded {}, skipped {}, remaining {}",
        v.planned,
        v.recorded,
        v.skipped.len(),
        v.remaining
    );
    let _ = writeln!(
        m,
        "- poses/hour {}",
        schema::fin(v.poses_per_hour).map_or("—".into(), |x| format!("{x:.0}"))
    );
    let t = &v.time;
    let _ = writeln!(
        m,
        "- time: move_s {:.1}, settle_s {:.1}, sample_s {:.1}, overhead_s {:.1}",
        t.move_s, t.settle_s, t.sample_s, t.overhead_s
    );
    let parts: Vec<String> = v.events.iter().map(|(k, x)| format!("{k} {x}")).collect();
    let _ = writeln!(
        m,
        "- events: {}",
        if parts.is_empty() {
            "none".into()
        } else {
            parts.join(", ")
        }
    );
    if let Some(a) = &v.aborted {
        let _ = writeln!(m, "- **aborted**: {}", cell(a));
    }
    if !v.skipped.is_empty() {
        // Group skips by reason.
        let mut by: std::collections::BTreeMap<&str, Vec<String>> = Default::default();
        for s in &v.skipped {
            by.entry(s.reason.as_str())
                .or_default()
                .push(s.id.to_string());
        }
        let _ = writeln!(m, "\n| skip reason | poses | ids |\n|---|---:|---|");
        for (reason, ids) in by {
            let _ = writeln!(
                m,
                "| {} | {} | {} |",
                cell(reason),
                ids.len(),
                ids.join(" ")
            );
        }
    }
    m.push('\n');
}

fn md_dataset(m: &mut String, d: &FoundDataset) {
    let _ = writeln!(m, "## Dataset (`{}`)\n", d.rel);
    let _ = writeln!(m, "```text\n{}```\n", d.summary);
}

fn md_calibration(m: &mut String, c: &Found<CalibrationFile>) {
    let v = &c.value;
    let _ = writeln!(
        m,
        "## Calibration `{}` (`{}`)\n",
        text(v.extra.get("kind")),
        c.rel
    );
    let _ = writeln!(
        m,
        "- robot {} serial {}",
        v.robot.model,
        v.robot.serial.as_deref().unwrap_or("—")
    );
    if !v.metrics.is_empty() {
        let _ = writeln!(m, "\n| metric | value |\n|---|---:|");
        for (k, x) in &v.metrics {
            let s = match num(Some(x)) {
                Some(f) if x.is_f64() => format!("{f:.4}"),
                _ => text(Some(x)),
            };
            let _ = writeln!(m, "| {} | {} |", cell(k), cell(&s));
        }
    }
    if let Ok(Some(b)) = v.camera() {
        let i = &b.intrinsics;
        let sd = |k: usize| {
            i.std
                .map_or("—".into(), |s| format!("± {:.3}", 1.96 * s[k]))
        };
        let _ = writeln!(
            m,
            "\nCamera {}×{} px: fx {:.3} {} fy {:.3} {} cx {:.3} {} cy {:.3} {} px; dist [{:.5}, {:.5}, {:.6}, {:.6}, {:.5}] ({}).",
            i.width,
            i.height,
            i.fx,
            sd(0),
            i.fy,
            sd(1),
            i.cx,
            sd(2),
            i.cy,
            sd(3),
            i.dist[0],
            i.dist[1],
            i.dist[2],
            i.dist[3],
            i.dist[4],
            i.model.as_deref().unwrap_or("—")
        );
        let h = &b.hand_eye;
        let ci = |v: Option<[f64; 3]>| {
            v.map_or("—".into(), |s| {
                format!(
                    "± [{:.3}, {:.3}, {:.3}]",
                    1.96 * s[0],
                    1.96 * s[1],
                    1.96 * s[2]
                )
            })
        };
        let _ = writeln!(
            m,
            "Hand-eye (camera in {}): xyz [{:.3}, {:.3}, {:.3}] mm {} (95 %), quat [{:.6}, {:.6}, {:.6}, {:.6}], rotation {} deg (95 %).",
            h.mount,
            h.xyz_mm[0],
            h.xyz_mm[1],
            h.xyz_mm[2],
            ci(h.std_mm),
            h.quat[0],
            h.quat[1],
            h.quat[2],
            h.quat[3],
            ci(h.std_deg)
        );
        if let Some(fm) = &b.flange_map {
            let r = |k: usize| {
                format!(
                    "[{:.2}, {:.2}, {:.2}]",
                    1e3 * fm.matrix[k][0],
                    1e3 * fm.matrix[k][1],
                    1e3 * fm.matrix[k][2]
                )
            };
            let _ = writeln!(
                m,
                "Flange positions read through a linear map (camera.flange_map): p + S·(p − c), \
                 c = ({:.1}, {:.1}, {:.1}) mm, S = [{}, {}, {}] mm/m; the hand-eye holds with it.",
                fm.centre_mm[0],
                fm.centre_mm[1],
                fm.centre_mm[2],
                r(0),
                r(1),
                r(2)
            );
        }
    }
    let free: Vec<_> = v.params.iter().filter(|p| p.free).collect();
    let fixed = v.params.len() - free.len();
    let _ = writeln!(
        m,
        "\n{} parameters ({} free, {} fixed):\n\n| parameter | value | std | unit | nominal |\n|---|---:|---:|---|---:|",
        v.params.len(),
        free.len(),
        fixed
    );
    for p in free {
        let _ = writeln!(
            m,
            "| {} | {:.5} | {} | {} | {} |",
            cell(&p.name),
            p.value,
            p.std.map_or("—".into(), |x| format!("{x:.5}")),
            cell(&p.unit),
            num(p.extra.get("nominal")).map_or("—".into(), |x| format!("{x:.5}")),
        );
    }
    if v.effects.is_empty() {
        let _ = writeln!(m, "\nEffects: none.");
    } else {
        let _ = writeln!(m, "\nEffects:");
        for e in &v.effects {
            let joint = e.joint.map(|j| format!(" (joint {j})"));
            let params = Value::Object(e.params.clone()).to_string();
            // A long parameter list (a transmission error map's 2·H coefficients, a kernel
            // correction's centres) says nothing a reader can use: its sentence instead.
            let shown = match crate::diagnose::effects::Effect::from_cal(e) {
                Ok(fx) if params.chars().count() > MAX_INLINE_PARAMS => format!(
                    "{} ({} values in calibration.json)",
                    fx.sentence(),
                    fx.coefs.len().max(e.params.len())
                ),
                _ => format!("`{}`", cell(&params)),
            };
            let _ = writeln!(m, "- {}{}: {shown}", e.kind, joint.unwrap_or_default());
        }
    }
    m.push('\n');
}

/// Effect parameters longer than this (characters of JSON) are summarised in the report by
/// the effect's sentence.
const MAX_INLINE_PARAMS: usize = 400;

fn md_diagnosis(m: &mut String, d: &Found<DiagnosisFile>) {
    let v = &d.value;
    let sensor = match v.sensor {
        DiagnosisSensor::Kinematic => "kinematic",
        DiagnosisSensor::Laser => "laser",
        DiagnosisSensor::Camera => "camera",
    };
    let _ = writeln!(m, "## Diagnosis (`{}`)\n", d.rel);
    let _ = writeln!(m, "Sensor: {sensor}; residual: {}.\n", v.residual);
    let ((unit, tn, tb, tf), (_, hn, hb, hf)) =
        (v.train_rms.with_unit(), v.heldout_rms.with_unit());
    let _ = writeln!(
        m,
        "| RMS ({unit}) | nominal | base model | final |\n|---|---:|---:|---:|\n| train ({}) | {} | {} | {} |\n| held-out ({}) | {} | {} | {} |",
        v.n_train,
        f3(tn),
        f3(tb),
        f3(tf),
        v.n_heldout,
        f3(hn),
        f3(hb),
        f3(hf),
    );
    if let Some(n) = &v.train_rms_near_heldout {
        // The training error where the held-out poses are (diagnose::region).
        let _ = writeln!(
            m,
            "| train, the {} poses nearest each held-out pose | — | {} | {} |",
            n.neighbours,
            f3(n.base_model_mm),
            f3(n.final_mm)
        );
    }
    m.push('\n');
    if let (Some(b), Some(a)) = (&v.hand_eye_before, &v.hand_eye_after) {
        let xyz = |x: &[f64; 3]| format!("[{:.3}, {:.3}, {:.3}]", x[0], x[1], x[2]);
        let _ = writeln!(
            m,
            "Hand-eye xyz (mm): {} → {} (after the effects).\n",
            xyz(&b.xyz_mm),
            xyz(&a.xyz_mm)
        );
    }
    if v.effects.is_empty() {
        let _ = writeln!(m, "No effect found beyond the base model.\n");
    } else {
        let _ = writeln!(
            m,
            "Chain (residual RMS → effect with evidence → new RMS):\n"
        );
        for (i, c) in v.effects.iter().enumerate() {
            let ev = &c.evidence;
            let (u, tb, ta, hb, ha) = c.rms_with_unit();
            let moved = match (c.hand_eye_change_mm, c.hand_eye_change_deg) {
                (Some(mm), Some(deg)) => format!("; hand-eye moved {mm:.4} mm, {deg:.5}°"),
                _ => String::new(),
            };
            let _ = writeln!(
                m,
                "{}. train {} {u} → **{}** (F {}, p {}, ΔBIC {}, CV gain {}) → {} {u}; held-out {} → {} {u}{moved}",
                i + 1,
                f3(tb),
                cell(&c.label),
                ev.f.map_or("—".into(), |x| format!("{x:.1}")),
                ev.p_value.map_or("—".into(), |x| format!("{x:.2e}")),
                ev.delta_bic.map_or("—".into(), |x| format!("{x:.1}")),
                f3(ev.cv_gain),
                f3(ta),
                f3(hb),
                f3(ha),
            );
            for p in &c.parameters {
                let ci = p
                    .ci95
                    .map_or(String::new(), |[a, b]| format!(" (95 %: {a:.4} … {b:.4})"));
                let _ = writeln!(m, "   - {} = {:.4} {}{ci}", p.name, p.value, p.unit);
            }
        }
        m.push('\n');
    }
    if v.nonparametric_used {
        let _ = writeln!(m, "A nonparametric correction was added for structured residual no named effect explained.\n");
    }
    if !v.ambiguous_heldout.is_empty() {
        let _ = writeln!(m, "Held-out poses inside a change point's window (ambiguous, not scored as errors of the model):");
        for a in &v.ambiguous_heldout {
            let _ = writeln!(
                m,
                "- pose {} at t = {:.1} s: {} stepped between {:.1} s and {:.1} s",
                a.id, a.t_s, a.effect, a.after_s, a.before_s
            );
        }
        m.push('\n');
    }
    if !v.not_identifiable.is_empty() {
        let _ = writeln!(m, "Not identifiable:");
        for x in &v.not_identifiable {
            let _ = writeln!(
                m,
                "- {} (ΔBIC {}, independence {})",
                x.candidate,
                x.delta_bic.map_or("—".into(), |x| format!("{x:.1}")),
                f3(x.independence)
            );
        }
        m.push('\n');
    }
    if !v.untestable.is_empty() {
        let _ = writeln!(m, "Untestable:");
        for x in &v.untestable {
            let _ = writeln!(m, "- {}: {}", x.effect, cell(&x.reason));
        }
        m.push('\n');
    }
    if !v.warnings.is_empty() {
        let _ = writeln!(m, "Diagnosis warnings:");
        for w in &v.warnings {
            let _ = writeln!(m, "- {}", cell(w));
        }
        m.push('\n');
    }
}

fn md_laser(m: &mut String, l: &Found<LaserReportFile>) {
    let v = &l.value;
    let _ = writeln!(m, "## Laser hand-eye methods (`{}`)\n", l.rel);
    let _ = writeln!(
        m,
        "| method | points | spread mm | FRE mm | TRE mm | RMS vs truth mm | note |\n|---|---:|---:|---:|---:|---:|---|"
    );
    for r in &v.rows {
        let spread = match (r.spread_mean_mm, r.spread_std_mm) {
            (Some(a), Some(s)) => format!("{a:.3} ± {s:.3}"),
            (Some(a), None) => format!("{a:.3}"),
            _ => "—".into(),
        };
        let _ = writeln!(
            m,
            "| {} | {} | {} | {} | {} | {} | {} |",
            cell(&r.method),
            r.n_used,
            spread,
            f3(r.fre_mm),
            f3(r.tre_mm),
            f3(r.spot_rms_vs_truth_mm),
            cell(&r.note),
        );
    }
    if let Some(x) = v.final_plane_rms_mm {
        let _ = writeln!(
            m,
            "\nFinal plane RMS {x:.4} mm ({}).",
            cell(&v.final_termination)
        );
    }
    m.push('\n');
}

fn md_scan(m: &mut String, s: &Found<ScanReportFile>) {
    let v = &s.value;
    let _ = writeln!(m, "## Laser scan (`{}`)\n", s.rel);
    let _ = writeln!(m, "{} points of `{}`.\n", v.points, cell(&v.scan));
    let _ = writeln!(
        m,
        "| face | points | flatness RMS mm | max mm |\n|---|---:|---:|---:|"
    );
    for f in &v.faces {
        let _ = writeln!(
            m,
            "| {} | {} | {:.4} | {:.4} |",
            cell(&f.face),
            f.points,
            f.rms_mm,
            f.max_mm
        );
    }
    for a in &v.angles {
        let _ = writeln!(m, "\n- angle {}/{}: {:.3}°", a.a, a.b, a.angle_deg);
    }
    m.push('\n');
}

fn md_pivot(m: &mut String, p: &Found<PivotFile>) {
    let v = &p.value;
    let _ = writeln!(
        m,
        "## Pivot calibration{} (`{}`)\n",
        v.tool
            .as_deref()
            .map_or(String::new(), |t| format!(" of {t}")),
        p.rel
    );
    let _ = writeln!(
        m,
        "| method | tip in marker mm | pivot point mm | RMS mm | max mm | frames |\n|---|---|---|---:|---:|---:|"
    );
    for r in &v.results {
        let t = r.tip_in_marker_mm;
        let q = r.pivot_point_mm;
        let _ = writeln!(
            m,
            "| {} | {:.3}, {:.3}, {:.3} | {:.3}, {:.3}, {:.3} | {:.4} | {:.4} | {} |",
            cell(&r.method),
            t[0],
            t[1],
            t[2],
            q[0],
            q[1],
            q[2],
            r.rms_mm,
            r.max_mm,
            r.frames
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
    /// The report as one self-contained HTML page: the Markdown text as HTML (headings,
    /// tables, lists) with every SVG plot inlined.
    pub fn html(&self) -> String {
        let mut h = String::new();
        h.push_str("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>robocal session report</title>\n");
        h.push_str("<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}pre{white-space:pre-wrap;font-size:13px;background:#f6f6f6;padding:.5em}table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 8px;text-align:left}code{background:#f4f4f4;padding:1px 4px;overflow-wrap:anywhere}h1.headline{font-size:1.3em}figure{margin:1em 0}</style>\n</head><body>\n");
        let _ = writeln!(
            h,
            "<h1 class=\"headline\">{}</h1>",
            html_escape(&self.headline_text())
        );
        // The Markdown's own title and headline are the page's heading above.
        let md = self.markdown();
        let body = md.splitn(3, "\n\n").nth(2).unwrap_or(md.as_str());
        h.push_str(&md_html::to_html(body));
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
