//! Plots of a camera session's held-out views: the reprojection RMS of each
//! held-out view with the calibration and with the diagnosed model, and the map of the
//! diagnosed model's residuals over the image (arrows, scaled). Computed by the validation
//! stage from the detected corners and `robocal predict`'s projection of each calibration
//! file (the figures the files deliver, not the fit's own residuals), written as SVG into
//! `validate/` and inlined by the report.
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use super::svg::esc;
use crate::solve::camera::View;

/// The held-out views' plots written into `dir/validate/`: their paths relative to `dir`.
pub fn write(
    dir: &Path,
    data: &Path,
    views: &[View],
    width: u32,
    height: u32,
) -> anyhow::Result<Vec<String>> {
    let predicted = |cal: &str| -> anyhow::Result<HashMap<(u64, usize), [f64; 2]>> {
        let rows = crate::solve::camera::calfile::predict_rows(&dir.join(cal), data)?;
        Ok(rows.into_iter().map(|(v, k, uv)| ((v, k), uv)).collect())
    };
    let before = predicted("calibrate/calibration.json")?;
    let after = predicted("diagnose/calibration.json")?;
    let (mut rms_b, mut rms_a, mut arrows) = (vec![], vec![], vec![]);
    for v in views {
        let (mut sb, mut sa, mut n) = (0.0, 0.0, 0usize);
        for (k, c) in v.corners.iter().enumerate() {
            let (Some(c), Some(pb), Some(pa)) = (c, before.get(&(v.id, k)), after.get(&(v.id, k)))
            else {
                continue;
            };
            sb += (c[0] - pb[0]).powi(2) + (c[1] - pb[1]).powi(2);
            sa += (c[0] - pa[0]).powi(2) + (c[1] - pa[1]).powi(2);
            arrows.push([c[0], c[1], c[0] - pa[0], c[1] - pa[1]]);
            n += 1;
        }
        if n > 0 {
            rms_b.push((sb / n as f64).sqrt());
            rms_a.push((sa / n as f64).sqrt());
        }
    }
    if rms_b.is_empty() {
        return Ok(vec![]);
    }
    let per_view = super::svg::before_after_unit(
        "Held-out reprojection RMS per view",
        "held-out view",
        "px",
        "before (calibration)",
        "after (diagnosed)",
        &rms_b,
        &rms_a,
    );
    let map = residual_map(&arrows, width, height);
    let mut out = vec![];
    for (name, svg) in [("heldout-views.svg", per_view), ("residual-map.svg", map)] {
        let p = dir.join("validate").join(name);
        super::write_atomic(&p, svg.as_bytes())?;
        out.push(super::rel(dir, &p));
    }
    Ok(out)
}

/// Residual arrows `[u, v, du, dv]` (px) drawn over the image frame, scaled so the longest is
/// about 40 px on the plot; the scale is in the title.
fn residual_map(arrows: &[[f64; 4]], width: u32, height: u32) -> String {
    let (w_img, h_img) = if width > 0 && height > 0 {
        (width as f64, height as f64)
    } else {
        // Unknown size: the corners' extent.
        let m = arrows
            .iter()
            .fold([1.0f64, 1.0], |m, a| [m[0].max(a[0]), m[1].max(a[1])]);
        (m[0] * 1.05, m[1] * 1.05)
    };
    let (pw, top, left) = (600.0, 36.0, 10.0);
    let s = pw / w_img;
    let ph = h_img * s;
    let longest = arrows.iter().map(|a| a[2].hypot(a[3])).fold(0.0, f64::max);
    // A round magnification (1, 2, 5 × 10^k): at most 40 px on the plot for the longest.
    let raw = if longest > 0.0 {
        40.0 / (longest * s)
    } else {
        1.0
    };
    let e = 10f64.powf(raw.log10().floor());
    let mag = [5.0, 2.0, 1.0]
        .iter()
        .map(|m| m * e)
        .find(|m| *m <= raw)
        .unwrap_or(e)
        .max(1.0);
    let rms = (arrows
        .iter()
        .map(|a| a[2] * a[2] + a[3] * a[3])
        .sum::<f64>()
        / arrows.len().max(1) as f64)
        .sqrt();
    let (w, h) = (pw + 2.0 * left, ph + top + 30.0);
    let mut o = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {w} {h}\" width=\"{w}\" height=\"{h}\" role=\"img\" aria-label=\"residual map\" font-family=\"sans-serif\" font-size=\"11\">\
         <rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\
         <text x=\"{cx}\" y=\"16\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{t}</text>\
         <rect x=\"{left}\" y=\"{top}\" width=\"{pw}\" height=\"{ph:.1}\" fill=\"none\" stroke=\"black\"/>",
        cx = w / 2.0,
        t = esc(&format!(
            "Held-out residuals over the image (diagnosed model): arrows ×{mag:.0}, RMS {rms:.3} px"
        )),
    );
    for a in arrows {
        let (x, y) = (left + a[0] * s, top + a[1] * s);
        let (x2, y2) = (x + a[2] * s * mag, y + a[3] * s * mag);
        let _ = write!(
            o,
            "<line x1=\"{x:.1}\" y1=\"{y:.1}\" x2=\"{x2:.1}\" y2=\"{y2:.1}\" stroke=\"#1f77b4\"/>\
             <circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"1\" fill=\"#555\"/>"
        );
    }
    let _ = write!(
        o,
        "<text x=\"{left}\" y=\"{ty:.1}\">image {:.0} × {:.0} px (u right, v down); dot: detected corner, arrow: detected − predicted</text></svg>",
        w_img,
        h_img,
        ty = top + ph + 18.0
    );
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_map_scales_arrows_and_states_the_scale() {
        let a = [[100.0, 100.0, 0.01, 0.0], [500.0, 300.0, 0.0, -0.02]];
        let svg = residual_map(&a, 640, 480);
        // 600/640 px per image px; the longest arrow 0.02 px → ×2000 (≤ 40 px / 0.01875).
        assert!(svg.contains("arrows ×2000"), "{svg}");
        assert!(svg.contains("RMS 0.016 px"), "{svg}");
        assert_eq!(svg.matches("<line").count(), 2);
    }
}
