//! The session report as one self-contained HTML page (inline CSS and SVG, no script, no
//! network): verdict first, SIMULATED / LIVE in large print, the cell, the criteria, plots,
//! effects in plain words, skipped poses, what to deploy and the datasets' SHA-256.
//!
//! The page is built only from artifacts of ONE session: every artifact's recorded dataset
//! SHA-256s must equal `session.json`'s, and the datasets on disk must still hash to them;
//! otherwise rendering fails naming the artifact.
use std::fmt::Write as _;
use std::path::Path;

use anyhow::{bail, Context as _};

use crate::session::svg::{self, esc};
use crate::session::{sha256_file, Mode, SessionFile, VerdictKind};

/// Artifacts that must carry the session's dataset fingerprint (if present).
const ARTIFACTS: [&str; 4] = [
    "calibrate/calibration.json",
    "diagnose/diagnosis.json",
    "diagnose/calibration.json",
    "deploy/calibration.json",
];

/// Checks that every artifact in `dir` belongs to the session `s` (same datasets).
pub fn check_same_session(dir: &Path, s: &SessionFile) -> anyhow::Result<()> {
    for d in &s.datasets {
        let p = dir.join(&d.path);
        let sha = sha256_file(&p)?;
        if sha != d.sha256 {
            bail!(
                "{}: SHA-256 {sha} differs from the {} dataset recorded in session.json ({}): \
                 refusing to report a session whose data changed",
                p.display(),
                d.role,
                d.sha256
            );
        }
    }
    let want = s.dataset_hashes();
    for a in ARTIFACTS {
        let p = dir.join(a);
        if !p.is_file() {
            continue;
        }
        let text = crate::fsio::read_to_string(&p).with_context(|| format!("{}", p.display()))?;
        let v: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}", p.display()))?;
        match v.get("datasets") {
            Some(got) if *got == want || subset_of(got, &want) => {}
            Some(got) => bail!(
                "{}: made from datasets {got}, but this session's are {want}: refusing to combine \
                 artifacts of different sessions",
                p.display()
            ),
            None => bail!(
                "{}: records no dataset SHA-256: cannot tell which session it belongs to",
                p.display()
            ),
        }
    }
    Ok(())
}

/// An artifact made before the session's later datasets existed (a laser calibration precedes
/// its held-out run): every dataset it names is one of the session's, with the same SHA-256.
fn subset_of(got: &serde_json::Value, want: &serde_json::Value) -> bool {
    match (got.as_object(), want.as_object()) {
        (Some(g), Some(w)) => !g.is_empty() && g.iter().all(|(role, sha)| w.get(role) == Some(sha)),
        _ => false,
    }
}

fn f4(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{x:.4}"))
}

fn inline_svg(path: &Path) -> Option<String> {
    let text = crate::fsio::read_to_string(path).ok()?;
    let start = text.find("<svg")?;
    // Only SVG markup (no script) is inlined.
    if text.contains("<script") {
        return None;
    }
    Some(text[start..].to_string())
}

/// Render the report of the session in `dir`.
pub fn render_session(dir: &Path, s: &SessionFile) -> anyhow::Result<String> {
    check_same_session(dir, s)?;
    let mut h = String::new();
    let (vclass, vcolour) = match s.verdict {
        VerdictKind::Pass => ("pass", "#1a7f37"),
        VerdictKind::Fail => ("fail", "#cf222e"),
        VerdictKind::Incomplete => ("incomplete", "#9a6700"),
    };
    let mode = match s.setup.mode {
        Mode::Sim => "SIMULATED",
        Mode::Live => "LIVE",
    };
    let title = format!(
        "{} — calibration of {} {}",
        s.verdict,
        s.cell.robot_model,
        s.cell.robot_serial.as_deref().unwrap_or("")
    );
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\
<style>body{{font-family:sans-serif;max-width:1000px;margin:1em auto;padding:0 1em;color:#222}}\
h1.verdict{{font-size:2.2em;color:white;background:{vcolour};padding:.4em .6em;border-radius:6px}}\
.mode{{font-size:2.6em;font-weight:bold;letter-spacing:.1em;border:4px solid #333;display:inline-block;padding:.1em .5em;margin:.2em 0}}\
table{{border-collapse:collapse;margin:.5em 0}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}\
.worse{{color:#cf222e;font-weight:bold}}.ok{{color:#1a7f37;font-weight:bold}}.bad{{color:#cf222e;font-weight:bold}}\
.flag{{border:3px solid #cf222e;background:#fff0f0;padding:.5em 1em;margin:1em 0}}\
code{{background:#f4f4f4;padding:1px 4px}}figure{{margin:1em 0}}</style></head><body>\n",
        esc(&title)
    );
    let _ = writeln!(
        h,
        "<h1 class=\"verdict {vclass}\" id=\"verdict\">{}</h1>",
        esc(&s.verdict_line)
    );
    let _ = writeln!(h, "<div class=\"mode\" id=\"mode\">{mode}</div>");
    if s.setup.mode == Mode::Sim {
        h.push_str("<p>Dry run on the simulated cell: no robot moved; the numbers show what the session would measure.</p>\n");
    }
    if let Some(j) = &s.judgement {
        if !j.worse.is_empty() {
            let _ = writeln!(
                h,
                "<div class=\"flag\" id=\"worse\"><b>Calibration made a held-out metric WORSE:</b><ul>{}</ul></div>",
                j.worse
                    .iter()
                    .map(|w| format!("<li class=\"worse\">{}</li>", esc(w)))
                    .collect::<String>()
            );
        }
    }
    // The cell.
    h.push_str("<h2>Cell</h2><table id=\"cell\">");
    let row = |h: &mut String, k: &str, v: &str| {
        let _ = write!(h, "<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
    };
    let c = &s.cell;
    row(&mut h, "Robot", &c.robot_model);
    row(
        &mut h,
        "Robot serial",
        c.robot_serial.as_deref().unwrap_or("—"),
    );
    row(&mut h, "Controller", c.controller.as_deref().unwrap_or("—"));
    row(&mut h, "Tracker", c.tracker.as_deref().unwrap_or("—"));
    // The tracker's name in the cell file (the tracker does not report its serial number
    // to robocal yet): not labelled a serial.
    row(
        &mut h,
        "Tracker name (cell file)",
        c.tracker_serial.as_deref().unwrap_or("—"),
    );
    row(
        &mut h,
        "Other sensors",
        &if c.sensors.is_empty() {
            "—".to_string()
        } else {
            c.sensors.join("; ")
        },
    );
    row(&mut h, "Session started (UTC)", &s.created);
    row(&mut h, "Last stage (UTC)", &s.updated);
    row(
        &mut h,
        "Operator note",
        s.setup.operator_note.as_deref().unwrap_or("—"),
    );
    row(&mut h, "Acceptance spec", &s.accept.name);
    if let Some(v) = &s.survey {
        // `--survey`: the plan was made from where the probe poses found the tracker.
        let w = crate::session::survey::words(v);
        row(&mut h, "Tracker survey", w.trim_start_matches("survey: "));
    }
    h.push_str("</table>\n");
    // Criteria.
    if let Some(j) = &s.judgement {
        h.push_str("<h2>Acceptance criteria</h2><table id=\"criteria\"><tr><th>criterion</th><th>limit</th><th>this session</th><th>result</th></tr>");
        for c in &j.criteria {
            let (cls, word) = match c.ok {
                Some(true) => ("ok", "pass"),
                Some(false) => ("bad", "FAIL"),
                None => ("bad", "not measured"),
            };
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td{}>{}</td><td class=\"{cls}\">{word}</td></tr>",
                esc(&c.name),
                esc(&c.limit),
                if c.value.contains("WORSE") {
                    " class=\"worse\""
                } else {
                    ""
                },
                esc(&c.value)
            );
        }
        h.push_str("</table>");
        for i in &j.incomplete {
            let _ = write!(h, "<p class=\"bad\">Incomplete: {}</p>", esc(i));
        }
    }
    // Numbers.
    let m = &s.measured;
    let ba = |b: Option<f64>, a: Option<f64>| -> String {
        let worse = matches!((b, a), (Some(b), Some(a)) if a > b);
        format!(
            "{} → {}{}",
            f4(b),
            f4(a),
            if worse {
                " <span class=\"worse\">WORSE</span>"
            } else {
                ""
            }
        )
    };
    h.push_str("<h2>Session</h2><table id=\"numbers\">");
    let _ = write!(
        h,
        "<tr><th>poses planned</th><td>{}</td></tr><tr><th>poses skipped</th><td>{}</td></tr>\
         <tr><th>predicted / measured acquisition time</th><td>{:.0} s / {}{}</td></tr>\
         <tr><th>held-out {}</th><td>{}</td></tr>",
        s.poses_planned,
        s.poses_skipped,
        s.predicted_duration_s,
        s.duration_s.map_or("—".into(), |d| format!("{d:.0} s")),
        if s.setup.mode == Mode::Sim {
            " (simulated clock)"
        } else {
            ""
        },
        if s.camera.is_some() {
            "views (with a board)"
        } else if s.rcm.is_some() {
            "endoscope views (lines detected)"
        } else {
            "poses"
        },
        m.heldout_poses,
    );
    if s.camera.is_some() {
        let _ = write!(
            h,
            "<tr><th>held-out reprojection RMS (px), calibration → diagnosed</th><td>{}</td></tr>",
            ba(
                m.heldout_reprojection_px_before,
                m.heldout_reprojection_px_after
            ),
        );
    } else if s.rcm.is_some() {
        let _ = write!(
            h,
            "<tr><th>held-out silhouette RMS (px), seed 002 two-step → ML</th><td>{}</td></tr>",
            ba(m.rcm_heldout_px_before, m.rcm_heldout_px_after),
        );
    } else {
        let _ = write!(
            h,
            "<tr><th>held-out RMS (mm), nominal → calibrated</th><td>{}</td></tr>\
             <tr><th>held-out max error (mm)</th><td>{}</td></tr>\
             <tr><th>relative distance error (%)</th><td>{}</td></tr>",
            ba(m.heldout_rms_mm_before, m.heldout_rms_mm_after),
            ba(m.heldout_max_mm_before, m.heldout_max_mm_after),
            ba(
                m.relative_distance_pct_before,
                m.relative_distance_pct_after
            ),
        );
    }
    h.push_str("</table>\n");
    // Plots.
    if !s.heldout_errors.is_empty() {
        let b: Vec<f64> = s.heldout_errors.iter().map(|e| e.before_mm).collect();
        let a: Vec<f64> = s.heldout_errors.iter().map(|e| e.after_mm).collect();
        let _ = write!(
            h,
            "<h2>Held-out error before / after</h2><figure id=\"plot-per-pose\">{}</figure><figure id=\"plot-histogram\">{}</figure>",
            svg::per_pose(&b, &a),
            svg::histogram(&b, &a)
        );
    }
    if let Some(v) = &s.verify {
        h.push_str(&crate::session::verify::html(v));
    }
    if let Some(c) = &s.camera {
        camera_section(&mut h, c);
        // The calibration's 95 % intervals (intrinsics, hand-eye, board).
        for svg in crate::session::camera_intervals::svgs(c) {
            let _ = write!(h, "<figure class=\"plot-camera-intervals\">{svg}</figure>");
        }
        // The held-out views: reprojection per view, residual map.
        for p in &c.plots {
            if let Some(svg) = inline_svg(&dir.join(p)) {
                let _ = write!(h, "<figure class=\"plot-camera\">{svg}</figure>");
            }
        }
    }
    if let Some(l) = &s.laser {
        h.push_str(&crate::session::laser::html(l, &s.measured));
    }
    if let Some(r) = &s.rcm {
        h.push_str(&crate::session::rcm::html(r, &s.measured));
    }
    if let Some(n) = &s.navchain {
        h.push_str(&crate::session::navchain::html(n));
    }
    // Effects.
    h.push_str("<h2>What the diagnosis found</h2>");
    if s.effects.is_empty() {
        h.push_str(if s.camera.is_some() {
            "<p id=\"effects\">No effect beyond the camera model (intrinsics, hand-eye, board pose) was found.</p>"
        } else {
            "<p id=\"effects\">No physical effect beyond the geometry was found.</p>"
        });
    } else {
        h.push_str("<ul id=\"effects\">");
        for e in &s.effects {
            let cls = if e.words.contains("WORSE") {
                " class=\"worse\""
            } else {
                ""
            };
            let _ = write!(h, "<li{cls}>{}</li>", esc(&e.words));
        }
        h.push_str("</ul>");
        for e in &s.effects {
            if let Some(svg) = e.plot.as_ref().and_then(|p| inline_svg(&dir.join(p))) {
                let _ = write!(
                    h,
                    "<figure class=\"effect-plot\"><figcaption>Residual against its regressor: {}</figcaption>{svg}</figure>",
                    esc(&e.kind)
                );
            }
        }
    }
    // Parameters.
    if !s.params.is_empty() {
        h.push_str("<h2>Parameter changes (calibrated − nominal, 95 % interval)</h2>");
        for unit in ["mm", "deg"] {
            let rows: Vec<(String, f64, Option<f64>)> = s
                .params
                .iter()
                .filter(|p| {
                    p.unit == unit && !p.name.starts_with("base") && !p.name.starts_with("tool")
                })
                .map(|p| (p.name.clone(), p.value - p.nominal, p.ci95))
                .collect();
            if !rows.is_empty() {
                let _ = write!(
                    h,
                    "<figure class=\"plot-params\">{}</figure>",
                    svg::param_changes(&format!("Arm parameters ({unit})"), unit, &rows)
                );
            }
        }
        h.push_str("<table id=\"params\"><tr><th>parameter</th><th>nominal</th><th>calibrated</th><th>change</th><th>95 % interval (±)</th></tr>");
        // -0.00000 prints as 0.00000.
        let z = |v: f64| if v.abs() < 5e-6 { 0.0 } else { v };
        for p in &s.params {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{:.5} {u}</td><td>{:.5} {u}</td><td>{:+.5} {u}</td><td>{}</td></tr>",
                esc(&p.name),
                z(p.nominal),
                z(p.value),
                z(p.value - p.nominal),
                p.ci95.map_or("—".into(), |c| format!("{c:.5} {}", esc(&p.unit))),
                u = esc(&p.unit)
            );
        }
        h.push_str("</table>");
    }
    // Skipped.
    h.push_str("<h2>Skipped poses</h2>");
    if s.skipped.is_empty() {
        h.push_str("<p id=\"skipped\">None: every planned pose was measured.</p>");
    } else {
        h.push_str("<table id=\"skipped\"><tr><th>set</th><th>pose</th><th>why</th></tr>");
        for k in &s.skipped {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&k.set),
                k.id,
                esc(&k.reason)
            );
        }
        h.push_str("</table>");
    }
    if !s.plan_rejects.is_empty() {
        let _ = write!(
            h,
            "<p>Candidate poses the planner left out before moving (cell geometry, limits): {}.</p>",
            esc(&s
                .plan_rejects
                .iter()
                .map(|(k, v)| format!("{k} {v}"))
                .collect::<Vec<_>>()
                .join(", "))
        );
    }
    // Deploy.
    h.push_str("<h2>What to deploy</h2>");
    if s.deploy.is_empty() {
        h.push_str("<p>Nothing yet: the session did not finish.</p>");
    } else if s.verdict != VerdictKind::Pass {
        h.push_str(
            "<p class=\"bad\">Do not deploy: the session did not pass its acceptance criteria.</p>",
        );
    }
    if !s.deploy.is_empty() {
        h.push_str("<ul id=\"deploy\">");
        for d in &s.deploy {
            let what = if s.camera.is_some() {
                "the camera calibration (robocal-calibration/1 `camera` block: intrinsics, hand-eye, board pose with their uncertainties; mm / degrees / px): `robocal predict --calibration` projects the board corners"
            } else if d.ends_with(".urdf") {
                "the calibrated geometry as URDF (metres, radians): load it in ROS / the navigation software in place of the nominal model; effects are not in it"
            } else {
                "the calibration file (robocal-calibration/1: geometry and effects, mm / degrees): `robocal predict --calibration` applies it"
            };
            let _ = write!(
                h,
                "<li><code>{}</code>: {}",
                esc(d),
                crate::report::md_html::inline(what)
            );
            // The accuracy this file delivers on its own, and a warning when that fails the
            // spec (the verdict was earned by the diagnosed model).
            if let Some(a) = s.deploy_accuracy.iter().find(|a| &a.artifact == d) {
                let rel = a
                    .relative_distance_pct
                    .map_or(String::new(), |r| format!(", relative distance {r:.3} %"));
                let _ = write!(
                    h,
                    "<br>alone, on the held-out poses: RMS {:.4} mm, max {:.4} mm{} — {}",
                    a.heldout_rms_mm,
                    a.heldout_max_mm,
                    esc(&rel),
                    if a.passes {
                        "<span class=\"ok\">meets the acceptance spec</span>".to_string()
                    } else {
                        format!(
                            "<span class=\"bad\">WARNING: alone it fails the acceptance spec ({})</span>",
                            esc(&a.fails.join("; "))
                        )
                    }
                );
            }
            h.push_str("</li>");
        }
        h.push_str("</ul>");
    }
    // Provenance.
    h.push_str("<h2>Datasets</h2><table id=\"datasets\"><tr><th>role</th><th>file</th><th>poses</th><th>SHA-256</th></tr>");
    for d in &s.datasets {
        let _ = write!(
            h,
            "<tr><td>{}</td><td><code>{}</code></td><td>{}</td><td><code>{}</code></td></tr>",
            esc(&d.role),
            esc(&d.path),
            d.records,
            esc(&d.sha256)
        );
    }
    h.push_str("</table>");
    if !s.warnings.is_empty() {
        h.push_str("<h2>Warnings</h2><ul>");
        for w in &s.warnings {
            let _ = write!(h, "<li>{}</li>", esc(w));
        }
        h.push_str("</ul>");
    }
    let _ = writeln!(
        h,
        "<p><small>robocal {} · session.json format {}</small></p></body></html>",
        env!("CARGO_PKG_VERSION"),
        esc(&s.format)
    );
    Ok(h)
}

/// The camera calibration of a camera session: intrinsics, hand-eye and board pose with
/// their 95 % intervals (the deployed, diagnosed values and the calibration stage's), every
/// method side by side, held-out pixels before / after the diagnosis.
/// A pose with its 1σ: xyz (mm), quaternion `[w, x, y, z]`, σ translation (mm), σ rotation
/// (deg, small rotations about the pose's own x, y, z axes).
type PoseSd = ([f64; 3], [f64; 4], Option<[f64; 3]>, Option<[f64; 3]>);

fn camera_section(h: &mut String, c: &crate::session::camera::CameraSummary) {
    let d = c.diagnosed.as_ref().unwrap_or(&c.calibrated);
    let ci = |sd: Option<f64>, p: usize| {
        sd.filter(|x| x.is_finite() && *x > 0.0)
            .map_or("—".into(), |x| format!("± {:.p$}", 1.96 * x))
    };
    let _ = write!(
        h,
        "<h2>Camera calibration</h2><section id=\"camera\"><p>{} training views with a board, {} held-out views{}; distortion model <code>{}</code> (chosen by validation error); {} views and {} corners rejected by residual. Intervals are 95 % (1.96 × the stated 1σ: the final fit's covariance or its view jackknife; for the calibration stage's hand-eye (and the deployed one when the diagnosis adds nothing), plus what the intrinsics' uncertainty, an undecided lens model and the choice among the estimators do to it).</p>",
        c.views_train,
        c.views_heldout,
        if c.views_without_board > 0 {
            format!(", {} without a usable board", c.views_without_board)
        } else {
            String::new()
        },
        esc(&c.distortion),
        c.rejected_views.len(),
        c.rejected_corners
    );
    // Intrinsics.
    let i = &d.intrinsics;
    let ic = &c.calibrated.intrinsics;
    let sd = |k: usize| i.std.map(|s| s[k]);
    h.push_str("<h3>Intrinsics</h3><table id=\"camera-intrinsics\"><tr><th>parameter</th><th>deployed (diagnosed)</th><th>95 %</th><th>calibration stage</th></tr>");
    let names = [
        "fx (px)", "fy (px)", "cx (px)", "cy (px)", "k1", "k2", "p1", "p2", "k3",
    ];
    let vals = [
        i.fx, i.fy, i.cx, i.cy, i.dist[0], i.dist[1], i.dist[2], i.dist[3], i.dist[4],
    ];
    let cal = [
        ic.fx, ic.fy, ic.cx, ic.cy, ic.dist[0], ic.dist[1], ic.dist[2], ic.dist[3], ic.dist[4],
    ];
    for k in 0..9 {
        let p = if k < 4 { 3 } else { 6 };
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.p$}</td><td>{}</td><td>{:.p$}</td></tr>",
            names[k],
            vals[k],
            ci(sd(k), p),
            cal[k]
        );
    }
    let _ = write!(
        h,
        "<tr><td>image</td><td colspan=\"3\">{} × {} px</td></tr></table>",
        i.width, i.height
    );
    // Hand-eye and board pose.
    let pose_rows = |h: &mut String,
                     label: &str,
                     p: PoseSd,
                     before: Option<([f64; 3], [f64; 4])>| {
        let (xyz, q, smm, sdeg) = p;
        let axes = ["x", "y", "z"];
        for k in 0..3 {
            let _ = write!(
                h,
                "<tr><td>{label} {} (mm)</td><td>{:.3}</td><td>{}</td><td>{}</td></tr>",
                axes[k],
                xyz[k],
                ci(smm.map(|s| s[k]), 3),
                before.map_or("—".into(), |b| format!("{:.3}", b.0[k]))
            );
        }
        let _ = write!(
            h,
            "<tr><td>{label} quaternion [w, x, y, z]</td><td>[{:.6}, {:.6}, {:.6}, {:.6}]</td><td>rotation {}</td><td>{}</td></tr>",
            q[0],
            q[1],
            q[2],
            q[3],
            sdeg.map_or("—".into(), |s| format!(
                "± {:.4}°, {:.4}°, {:.4}° (about its own x, y, z axes)",
                1.96 * s[0],
                1.96 * s[1],
                1.96 * s[2]
            )),
            before.map_or("—".into(), |b| format!(
                "[{:.6}, {:.6}, {:.6}, {:.6}]",
                b.1[0], b.1[1], b.1[2], b.1[3]
            ))
        );
    };
    let he = &d.hand_eye;
    let _ = write!(
        h,
        "<h3>Hand-eye</h3><p>The camera frame (OpenCV axes) in the {} frame{}.</p><table id=\"camera-hand-eye\"><tr><th>parameter</th><th>deployed (diagnosed)</th><th>95 %</th><th>calibration stage</th></tr>",
        if he.mount == "flange" { "flange" } else { "robot base" },
        if he.mount == "flange" { " (eye-in-hand)" } else { " (eye-to-hand)" }
    );
    pose_rows(
        h,
        "hand-eye",
        (he.xyz_mm, he.quat, he.std_mm, he.std_deg),
        Some((c.calibrated.hand_eye.xyz_mm, c.calibrated.hand_eye.quat)),
    );
    let (tlabel, t, tc) = match (&d.target_in_base, &d.target_in_flange) {
        (Some(t), _) => ("board in base", t, c.calibrated.target_in_base.as_ref()),
        (None, Some(t)) => ("board in flange", t, c.calibrated.target_in_flange.as_ref()),
        _ => {
            h.push_str("</table>");
            return;
        }
    };
    pose_rows(
        h,
        tlabel,
        (t.xyz_mm, t.quat, t.std_mm, t.std_deg),
        tc.map(|p| (p.xyz_mm, p.quat)),
    );
    if let Some(sc) = d.target_scale {
        let _ = write!(
            h,
            "<tr><td>board scale (printed / declared)</td><td>{sc:.6}</td><td>—</td><td>1</td></tr>"
        );
    }
    if let Some(b) = d.target_bend_mm {
        let _ = write!(
            h,
            "<tr><td>board sag x, y (mm)</td><td>{:.4}, {:.4}</td><td>—</td><td>0, 0</td></tr>",
            b[0], b[1]
        );
    }
    if let Some(m) = &d.flange_map {
        let largest = m
            .matrix
            .iter()
            .flatten()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        let c = m.centre_mm;
        let _ = write!(
            h,
            "<tr><td>flange positions read through a linear map (largest entry, about the centre)</td>\
             <td>{:.2} mm/m about ({:.0}, {:.0}, {:.0}) mm</td><td>—</td><td>none</td></tr>",
            1e3 * largest,
            c[0],
            c[1],
            c[2]
        );
    }
    h.push_str("</table>");
    // Held-out pixels.
    let _ = write!(
        h,
        "<h3>Reprojection</h3><table id=\"camera-reprojection\"><tr><th></th><th>calibration (maximum likelihood)</th><th>diagnosed (deployed)</th></tr>\
         <tr><th>held-out RMS (px)</th><td>{}</td><td>{}</td></tr><tr><th>training RMS (px)</th><td>{:.4}</td><td>{}</td></tr></table>",
        f4(c.heldout_rms_px_calibrated),
        f4(c.heldout_rms_px_diagnosed),
        c.train_rms_px,
        f4(c.train_rms_px_diagnosed)
    );
    if let (Some(mm), Some(deg)) = (c.hand_eye_heldout_diff_mm, c.hand_eye_heldout_diff_deg) {
        let _ = write!(
            h,
            "<p id=\"camera-hand-eye-check\">Hand-eye check on independent data: the {} held-out views calibrated on their own (through the deployed arm and board scale) put the camera {mm:.3} mm and {deg:.4}° from the deployed hand-eye.</p>",
            c.views_heldout
        );
    }
    // Methods side by side.
    h.push_str("<h3>Hand-eye methods side by side</h3><table id=\"camera-methods\"><tr><th>method</th><th>train RMS (px)</th><th>held-out RMS (px)</th><th>hand-eye x, y, z (mm)</th></tr>");
    for r in &c.methods {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{:.4}</td><td>{}</td><td>{:.3}, {:.3}, {:.3}</td></tr>",
            esc(&r.method),
            r.train_rms_px,
            f4(r.heldout_rms_px),
            r.hand_eye_xyz_mm[0],
            r.hand_eye_xyz_mm[1],
            r.hand_eye_xyz_mm[2]
        );
    }
    h.push_str("</table></section>\n");
}
