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
    frame_head(s, title, xlabel, ylabel);
    for k in 0..=4 {
        let v = ymin + (ymax - ymin) * k as f64 / 4.0;
        let y = H - B - (H - B - T) * k as f64 / 4.0;
        grid_line(s, y, &tick(v));
    }
}

/// A horizontal grid line at `y` labelled `label` on the y axis.
fn grid_line(s: &mut String, y: f64, label: &str) {
    let _ = write!(
        s,
        "<line x1=\"{L}\" x2=\"{x2}\" y1=\"{y:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>\
         <text x=\"{tx}\" y=\"{ty:.1}\" text-anchor=\"end\">{label}</text>",
        x2 = W - R,
        tx = L - 4.0,
        ty = y + 4.0
    );
}

/// The plot's frame: title, axis labels, axes (no ticks).
fn frame_head(s: &mut String, title: &str, xlabel: &str, ylabel: &str) {
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
    let t = if v != 0.0 && v.abs() < 0.001 {
        format!("{v:.7}")
    } else {
        format!("{v:.3}")
    };
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t == "-0" {
        "0".into()
    } else {
        t.into()
    }
}

fn legend(s: &mut String, items: &[(&str, &str)]) {
    // Wide enough for the longest label (about 6.2 px a character at 11 px).
    let chars = items
        .iter()
        .map(|(l, _)| l.chars().count())
        .max()
        .unwrap_or(0);
    let x = W - R - (20.0 + 6.2 * chars as f64).max(150.0);
    for (i, (label, colour)) in items.iter().enumerate() {
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

/// The decades `[10^lo, 10^hi]` that hold every positive finite value of `v`, when they span
/// more than `ratio` (a linear axis would flatten the small ones to its floor).
fn log_span(v: &[f64], ratio: f64) -> Option<(i32, i32)> {
    let pos = v.iter().copied().filter(|x| x.is_finite() && *x > 0.0);
    let (lo, hi) = pos.fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
    // The top decade keeps room for the legend above the largest value.
    (lo.is_finite() && hi / lo > ratio).then(|| {
        let l = lo.log10().floor() as i32;
        (l, ((hi.log10() + 0.4).ceil() as i32).max(l + 1))
    })
}

/// A log-scale y axis from `10^lo` to `10^hi`: grid and labels at each decade.
fn frame_log(s: &mut String, title: &str, xlabel: &str, ylabel: &str, lo: i32, hi: i32) {
    frame_head(s, title, xlabel, ylabel);
    for k in lo..=hi {
        let y = H - B - (H - B - T) * (k - lo) as f64 / (hi - lo) as f64;
        grid_line(s, y, &tick(10f64.powi(k)));
    }
}

/// Before / after dot pairs along x (one pair per item); red where after > before. A log
/// axis when the errors span more than 20× (a calibration's "after" would sit on the floor
/// of a linear one).
pub fn before_after(title: &str, xlabel: &str, before: &[f64], after: &[f64]) -> String {
    before_after_unit(
        title,
        xlabel,
        "mm",
        "before (nominal)",
        "after",
        before,
        after,
    )
}

/// [`before_after`] in `unit`, with its own legend words.
pub fn before_after_unit(
    title: &str,
    xlabel: &str,
    unit: &str,
    before_label: &str,
    after_label: &str,
    before: &[f64],
    after: &[f64],
) -> String {
    let n = before.len().max(1);
    let all: Vec<f64> = before.iter().chain(after).copied().collect();
    let mut s = String::new();
    let y: Box<dyn Fn(f64) -> f64> = match log_span(&all, 20.0) {
        Some((lo, hi)) => {
            frame_log(
                &mut s,
                title,
                xlabel,
                &format!("error ({unit}, log scale)"),
                lo,
                hi,
            );
            let (a, b) = (lo as f64, hi as f64);
            Box::new(move |v: f64| {
                let l = v.max(10f64.powf(a)).log10();
                H - B - (H - B - T) * ((l - a) / (b - a)).clamp(0.0, 1.0)
            })
        }
        None => {
            let ymax = nice_max(
                all.iter()
                    .copied()
                    .filter(|x| x.is_finite())
                    .fold(0.0, f64::max),
            );
            frame(&mut s, title, xlabel, &format!("error ({unit})"), 0.0, ymax);
            Box::new(move |v: f64| H - B - (H - B - T) * (v / ymax).clamp(0.0, 1.0))
        }
    };
    let dx = (W - L - R) / n as f64;
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
    let worse = format!("{after_label}, WORSE");
    let mut items = vec![(before_label, "#999"), (after_label, "#1f77b4")];
    if before.iter().zip(after).any(|(b, a)| a > b) {
        items.push((worse.as_str(), "#d62728"));
    }
    legend(&mut s, &items);
    s.push_str("</svg>");
    s
}

/// Histogram of the held-out errors before and after: log-spaced bins (4 a decade) when the
/// errors span more than 20× (else the "after" would fill the first bin of a linear axis).
pub fn histogram(before: &[f64], after: &[f64]) -> String {
    let all: Vec<f64> = before.iter().chain(after).copied().collect();
    let span = log_span(&all, 20.0);
    let xmax = nice_max(
        all.iter()
            .copied()
            .filter(|x| x.is_finite())
            .fold(0.0, f64::max),
    );
    let bins = match span {
        Some((lo, hi)) => 4 * (hi - lo) as usize,
        None => 20,
    };
    // The bin of a value (0 … bins-1).
    let bin = |x: f64| -> usize {
        let f = match span {
            Some((lo, hi)) => (x.max(10f64.powi(lo)).log10() - lo as f64) / (hi - lo) as f64,
            None => x / xmax,
        };
        (f * bins as f64).floor().clamp(0.0, bins as f64 - 1.0) as usize
    };
    let count = |v: &[f64]| {
        let mut c = vec![0usize; bins];
        for x in v.iter().filter(|x| x.is_finite()) {
            c[bin(*x)] += 1;
        }
        c
    };
    let (cb, ca) = (count(before), count(after));
    // Integer count ticks, four steps; the top fifth kept free for the legend.
    let top = cb.iter().chain(&ca).copied().max().unwrap_or(1).max(1);
    let step = (nice_max(top as f64 / 0.8 / 4.0)).ceil().max(1.0);
    let ymax = step * 4.0;
    let mut s = String::new();
    frame(
        &mut s,
        "Held-out error histogram",
        if span.is_some() {
            "error (mm, log scale)"
        } else {
            "error (mm)"
        },
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
    let ticks: Vec<(usize, f64)> = match span {
        Some((lo, hi)) => (lo..=hi)
            .map(|k| (4 * (k - lo) as usize, 10f64.powi(k)))
            .collect(),
        None => [0, bins / 2, bins]
            .iter()
            .map(|k| (*k, xmax * *k as f64 / bins as f64))
            .collect(),
    };
    for (k, v) in ticks {
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>",
            L + bw * k as f64,
            H - B + 14.0,
            tick(v)
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
///
/// Each interval ends in caps. One narrower than its dot (half-width under [`MIN_HALF_PX`]
/// px) would vanish behind it: its caps are drawn at ± [`MIN_HALF_PX`] px instead, joined by a
/// thin line, with the true half-width in a tooltip and a footnote saying what the caps mean.
pub fn param_changes(title: &str, unit: &str, rows: &[(String, f64, Option<f64>)]) -> String {
    let lim = nice_max(
        rows.iter()
            .map(|(_, d, c)| d.abs() + c.unwrap_or(0.0))
            .fold(0.0, f64::max),
    );
    let (l, r) = (110.0, W - 20.0);
    let x = |v: f64| l + (r - l) * (v + lim) / (2.0 * lim);
    let narrow = |c: f64| (x(c) - x(0.0)) < MIN_HALF_PX;
    let any_narrow = rows.iter().any(|(_, _, c)| c.is_some_and(narrow));
    let h = 40.0 + 16.0 * rows.len() as f64 + 30.0 + if any_narrow { 14.0 } else { 0.0 };
    let axis_y = if any_narrow { h - 22.0 } else { h - 8.0 };
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {h}\" width=\"{W}\" height=\"{h}\" role=\"img\" aria-label=\"{t}\" font-family=\"sans-serif\" font-size=\"11\">\
         <rect width=\"{W}\" height=\"{h}\" fill=\"white\"/>\
         <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{t}</text>\
         <line x1=\"{x0}\" x2=\"{x0}\" y1=\"28\" y2=\"{yb}\" stroke=\"black\"/>",
        t = esc(title),
        cx = W / 2.0,
        x0 = x(0.0),
        yb = axis_y - 16.0
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
        if let Some(c) = *ci {
            interval(&mut s, x(*d), y, x(d - c), x(d + c), c, unit);
        }
        let _ = write!(
            s,
            "<circle cx=\"{:.1}\" cy=\"{y}\" r=\"{DOT_R}\" fill=\"black\"/>",
            x(*d)
        );
    }
    for (v, anchor) in [(-lim, "start"), (0.0, "middle"), (lim, "end")] {
        let label = if v == 0.0 {
            "0".to_string()
        } else {
            format!(
                "{}{} {}",
                if v > 0.0 { "+" } else { "" },
                tick(v),
                esc(unit)
            )
        };
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"{anchor}\">{label}</text>",
            x(v),
            axis_y
        );
    }
    if any_narrow {
        let _ = write!(
            s,
            "<text x=\"{l}\" y=\"{}\" font-size=\"10\" fill=\"#555\">{NARROW_NOTE}</text>",
            h - 6.0
        );
    }
    s.push_str("</svg>");
    s
}

/// The dot's radius (px) in [`param_changes`].
const DOT_R: f64 = 3.0;
/// The least half-width (px) an interval is drawn with: twice the dot's radius.
pub const MIN_HALF_PX: f64 = 2.0 * DOT_R;
/// The footnote of a plot with an interval drawn at the least width.
pub const NARROW_NOTE: &str =
    "Grey caps: an interval narrower than its dot, drawn wider to be seen (hover: its value).";

/// One row's 95 % interval around the dot at `xd`: the bar from `a` to `b` with caps, or, when
/// narrower than [`MIN_HALF_PX`] each side, grey caps at ± [`MIN_HALF_PX`] joined by a thin
/// line (the true half-width `c` in the tooltip).
fn interval(s: &mut String, xd: f64, y: f64, a: f64, b: f64, c: f64, unit: &str) {
    let narrow = (b - a) / 2.0 < MIN_HALF_PX;
    let (a, b, colour, width) = if narrow {
        (xd - MIN_HALF_PX, xd + MIN_HALF_PX, "#777", 1)
    } else {
        (a, b, "#1f77b4", 2)
    };
    let _ = write!(
        s,
        "<g class=\"ci{}\" stroke=\"{colour}\" stroke-width=\"{width}\"><title>95 % interval ±{} {}</title>\
         <line x1=\"{a:.1}\" x2=\"{b:.1}\" y1=\"{y}\" y2=\"{y}\"/>\
         <line x1=\"{a:.1}\" x2=\"{a:.1}\" y1=\"{}\" y2=\"{}\"/>\
         <line x1=\"{b:.1}\" x2=\"{b:.1}\" y1=\"{}\" y2=\"{}\"/></g>",
        if narrow { " narrow" } else { "" },
        tick(c),
        esc(unit),
        y - 4.0,
        y + 4.0,
        y - 4.0,
        y + 4.0,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(c: &[Option<f64>]) -> Vec<(String, f64, Option<f64>)> {
        c.iter()
            .enumerate()
            .map(|(i, c)| (format!("p{i}"), 1.0 - i as f64, *c))
            .collect()
    }

    /// The caps' x positions of the interval groups of `svg`, per group.
    fn caps(svg: &str) -> Vec<(bool, f64, f64)> {
        svg.split("<g class=\"ci")
            .skip(1)
            .map(|g| {
                let xs: Vec<f64> = g
                    .split("x1=\"")
                    .skip(2)
                    .map(|t| t.split('"').next().unwrap().parse().unwrap())
                    .collect();
                (g.starts_with(" narrow"), xs[0], xs[1])
            })
            .collect()
    }

    #[test]
    fn an_interval_narrower_than_its_dot_is_drawn_at_the_least_width() {
        // Plot range ±2 over 510 px: 1e-4 is 0.01 px, far inside the dot; 0.5 is 64 px.
        let svg = param_changes("t", "px", &rows(&[Some(1e-4), Some(0.5), None]));
        let c = caps(&svg);
        assert_eq!(c.len(), 2, "{svg}");
        let (narrow, a, b) = c[0];
        assert!(narrow, "{svg}");
        assert!(
            ((b - a) / 2.0 - MIN_HALF_PX).abs() < 0.11,
            "narrow caps at {a}, {b}"
        );
        assert!(svg.contains("95 % interval ±0.0001 px"), "{svg}");
        let (narrow, a, b) = c[1];
        assert!(!narrow && (b - a) / 2.0 > 50.0, "wide caps at {a}, {b}");
        assert!(svg.contains(NARROW_NOTE), "{svg}");
        // With no narrow interval: no grey caps and no footnote.
        let svg = param_changes("t", "px", &rows(&[Some(0.5), Some(0.3)]));
        assert!(caps(&svg).iter().all(|c| !c.0) && !svg.contains(NARROW_NOTE));
    }
}
