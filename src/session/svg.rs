//! Small self-contained SVG plots for the session report (no scripts, no external fonts).
use std::fmt::Write as _;

/// XML-escape text.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const W: f64 = 640.0;
const H: f64 = 260.0;
const L: f64 = 60.0;
const R: f64 = 20.0;
const T: f64 = 30.0;
const B: f64 = 40.0;

fn nice_max(v: f64) -> f64 {
    if !(v.is_finite() && v > 0.0) {
        return 1.0;
    }
    let e = 10f64.powf(v.log10().floor());
    for m in [1.0, 2.0, 2.5, 5.0, 10.0] {
        if m * e >= v {
            return m * e;
        }
    }
    10.0 * e
}

fn frame(s: &mut String, title: &str, xlabel: &str, ylabel: &str, ymin: f64, ymax: f64) {
    let _ = write!(
        s,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {H}\" width=\"{W}\" height=\"{H}\" role=\"img\" aria-label=\"{t}\" font-family=\"sans-serif\" font-size=\"11\">\
         <rect x=\"0\" y=\"0\" width=\"{W}\" height=\"{H}\" fill=\"white\"/>\
         <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{t}</text>\
         <text x=\"{cx}\" y=\"{xl}\" text-anchor=\"middle\">{xlab}</text>\
         <text x=\"14\" y=\"{cy}\" text-anchor=\"middle\" transform=\"rotate(-90 14 {cy})\">{ylab}</text>",
        t = esc(title),
        cx = (L + W - R) / 2.0,
        xl = H - 6.0,
        xlab = esc(xlabel),
        cy = (T + H - B) / 2.0,
        ylab = esc(ylabel),
    );
    for k in 0..=4 {
        let v = ymin + (ymax - ymin) * k as f64 / 4.0;
        let y = H - B - (H - B - T) * k as f64 / 4.0;
        let _ = write!(
            s,
            "<line x1=\"{L}\" x2=\"{x2}\" y1=\"{y:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>\
             <text x=\"{tx}\" y=\"{ty:.1}\" text-anchor=\"end\">{v}</text>",
            v = tick(v),
            x2 = W - R,
            tx = L - 4.0,
            ty = y + 4.0
        );
    }
    let _ = write!(
        s,
        "<line x1=\"{L}\" x2=\"{L}\" y1=\"{T}\" y2=\"{yb}\" stroke=\"black\"/>\
         <line x1=\"{L}\" x2=\"{x2}\" y1=\"{yb}\" y2=\"{yb}\" stroke=\"black\"/>",
        yb = H - B,
        x2 = W - R
    );
}

/// A tick label without trailing zeros (counts print as integers).
fn tick(v: f64) -> String {
    let t = format!("{v:.3}");
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t == "-0" {
        "0".into()
    } else {
        t.into()
    }
}

fn legend(s: &mut String, items: &[(&str, &str)]) {
    for (i, (label, colour)) in items.iter().enumerate() {
        let x = W - R - 150.0;
        let y = T + 6.0 + 16.0 * i as f64;
        let _ = write!(
            s,
            "<rect x=\"{x}\" y=\"{y}\" width=\"10\" height=\"10\" fill=\"{colour}\"/>\
             <text x=\"{tx}\" y=\"{ty}\">{l}</text>",
            tx = x + 14.0,
            ty = y + 9.0,
            l = esc(label)
        );
    }
}

/// Held-out error per pose, before (grey) and after (blue; red where it got worse).
pub fn per_pose(before: &[f64], after: &[f64]) -> String {
    before_after("Held-out error per pose", "held-out pose", before, after)
}

/// Before / after dot pairs along x (one pair per item); red where after > before.
pub fn before_after(title: &str, xlabel: &str, before: &[f64], after: &[f64]) -> String {
    let n = before.len().max(1);
    let ymax = nice_max(
        before
            .iter()
            .chain(after)
            .cloned()
            .filter(|x| x.is_finite())
            .fold(0.0, f64::max),
    );
    let mut s = String::new();
    frame(&mut s, title, xlabel, "error (mm)", 0.0, ymax);
    let dx = (W - L - R) / n as f64;
    let y = |v: f64| H - B - (H - B - T) * (v / ymax).clamp(0.0, 1.0);
    for (i, (b, a)) in before.iter().zip(after).enumerate() {
        if !(b.is_finite() && a.is_finite()) {
            continue;
        }
        let x = L + dx * (i as f64 + 0.5);
        let colour = if a > b { "#d62728" } else { "#1f77b4" };
        let _ = write!(
            s,
            "<line x1=\"{x:.1}\" x2=\"{x:.1}\" y1=\"{yb:.1}\" y2=\"{ya:.1}\" stroke=\"#bbb\"/>\
             <circle cx=\"{x:.1}\" cy=\"{yb:.1}\" r=\"3\" fill=\"#999\"/>\
             <circle cx=\"{x:.1}\" cy=\"{ya:.1}\" r=\"3\" fill=\"{colour}\"/>",
            yb = y(*b),
            ya = y(*a)
        );
    }
    let mut items = vec![("before (nominal)", "#999"), ("after", "#1f77b4")];
    if before.iter().zip(after).any(|(b, a)| a > b) {
        items.push(("after, WORSE", "#d62728"));
    }
    legend(&mut s, &items);
    s.push_str("</svg>");
    s
}

/// Histogram of the held-out errors before and after.
pub fn histogram(before: &[f64], after: &[f64]) -> String {
    let xmax = nice_max(before.iter().chain(after).cloned().fold(0.0, f64::max));
    let bins = 20;
    let count = |v: &[f64]| {
        let mut c = vec![0usize; bins];
        for x in v {
            let k = ((x / xmax) * bins as f64)
                .floor()
                .clamp(0.0, bins as f64 - 1.0) as usize;
            c[k] += 1;
        }
        c
    };
    let (cb, ca) = (count(before), count(after));
    let ymax = nice_max(cb.iter().chain(&ca).copied().max().unwrap_or(1) as f64);
    let mut s = String::new();
    frame(
        &mut s,
        "Held-out error histogram",
        &format!("error (mm), 0 to {xmax}"),
        "poses",
        0.0,
        ymax,
    );
    let bw = (W - L - R) / bins as f64;
    for (k, (b, a)) in cb.iter().zip(&ca).enumerate() {
        let x = L + bw * k as f64;
        for (v, off, colour) in [(*b, 0.0, "#999"), (*a, bw / 2.0, "#1f77b4")] {
            let h = (H - B - T) * v as f64 / ymax;
            let _ = write!(
                s,
                "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{h:.1}\" fill=\"{colour}\"/>",
                x + off,
                H - B - h,
                bw / 2.0 - 1.0
            );
        }
    }
    for k in [0, bins / 2, bins] {
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>",
            L + bw * k as f64,
            H - B + 14.0,
            tick(xmax * k as f64 / bins as f64)
        );
    }
    legend(
        &mut s,
        &[("before (nominal)", "#999"), ("after", "#1f77b4")],
    );
    s.push_str("</svg>");
    s
}

/// Parameter changes (value − nominal) with 95 % intervals, one row per parameter.
pub fn param_changes(title: &str, unit: &str, rows: &[(String, f64, Option<f64>)]) -> String {
    let h = 40.0 + 16.0 * rows.len() as f64 + 30.0;
    let lim = nice_max(
        rows.iter()
            .map(|(_, d, c)| d.abs() + c.unwrap_or(0.0))
            .fold(0.0, f64::max),
    );
    let (l, r) = (110.0, W - 20.0);
    let x = |v: f64| l + (r - l) * (v + lim) / (2.0 * lim);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {h}\" width=\"{W}\" height=\"{h}\" role=\"img\" aria-label=\"{t}\" font-family=\"sans-serif\" font-size=\"11\">\
         <rect width=\"{W}\" height=\"{h}\" fill=\"white\"/>\
         <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{t}</text>\
         <line x1=\"{x0}\" x2=\"{x0}\" y1=\"28\" y2=\"{yb}\" stroke=\"black\"/>",
        t = esc(title),
        cx = W / 2.0,
        x0 = x(0.0),
        yb = h - 24.0
    );
    for (i, (name, d, ci)) in rows.iter().enumerate() {
        let y = 40.0 + 16.0 * i as f64;
        let _ = write!(
            s,
            "<text x=\"{tx}\" y=\"{ty}\" text-anchor=\"end\">{n}</text>",
            tx = l - 6.0,
            ty = y + 4.0,
            n = esc(name)
        );
        if let Some(c) = ci {
            let _ = write!(
                s,
                "<line x1=\"{:.1}\" x2=\"{:.1}\" y1=\"{y}\" y2=\"{y}\" stroke=\"#1f77b4\" stroke-width=\"2\"/>",
                x(d - c),
                x(d + c)
            );
        }
        let _ = write!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{y}\" r=\"3\" fill=\"black\"/>",
            x(*d)
        );
    }
    for v in [-lim, 0.0, lim] {
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{v:+.4} {u}</text>",
            x(v),
            h - 8.0,
            u = esc(unit)
        );
    }
    s.push_str("</svg>");
    s
}
