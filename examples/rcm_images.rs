//! Issue 29 §2: the RCM endoscope calibration from rendered images. Over `--trials` trials of
//! `--poses` planned poses, the world renders each endoscope view, the detector finds the
//! shaft's silhouettes in the pixels, and this prints the line error against the world's exact
//! silhouettes (px, deg) and the hand-eye error with detected vs exact lines.
//!
//! `cargo run --example rcm_images [-- --trials 20 --poses 20 --robot-mm 0.05 --robot-deg 0.02]`
#[path = "common/rcm_trials.rs"]
mod rcm_trials;

use rcm_trials::{run, text, TrialOptions};
use robocal_mocks::rcm::RcmScenario;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let mut o = TrialOptions::default();
    if let Some(v) = arg("--trials") {
        o.trials = v.parse()?;
    }
    if let Some(v) = arg("--poses") {
        o.poses = v.parse()?;
    }
    if let Some(v) = arg("--robot-mm") {
        o.robot_mm = v.parse()?;
    }
    if let Some(v) = arg("--robot-deg") {
        o.robot_deg = v.parse()?;
    }
    if let Some(dir) = arg("--dump") {
        return dump(&o, std::path::Path::new(&dir));
    }
    let t = std::time::Instant::now();
    let r = run(&RcmScenario::builtin(), &o)?;
    print!("{}", text(&o, &r));
    println!("wall {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

/// `--dump DIR`: the first trial's views as PGM, with the world's silhouettes, every straight
/// edge found and the detector's choice (for looking at what the detector sees).
fn dump(o: &TrialOptions, dir: &std::path::Path) -> anyhow::Result<()> {
    use robocal::plan::rcm::{generate, RcmPlanSpec};
    use robocal::solve::rcm::lines;
    use robocal_mocks::rcm::RcmCell;
    use robocal_mocks::rcm_render::RcmRenderer;
    std::fs::create_dir_all(dir)?;
    let cell = RcmCell::new(RcmScenario::builtin());
    let rr = RcmRenderer::new(&cell, &cell.scenario.render);
    let cam = rcm_trials::endoscope_camera(&cell.scenario);
    let model = robocal::model::KinematicModel::preset(&cell.scenario.robot)?;
    let spec = RcmPlanSpec {
        trocar_mm: cell.scenario.trocar_mm,
        insertion_dir: cell.scenario.insertion_dir,
        x_hint: [0.0, 1.0, 0.0],
        pivot_deg: o.pivot_deg,
        insertion_mm: o.insertion_mm,
        roll_deg: 10.0,
        count: o.poses,
        seed: o.seed,
        shaft_length_mm: 350.0,
    };
    for (i, p) in generate(&spec, Some(&model))?.iter().enumerate() {
        let Some(v) = cell.view(&p.instrument) else {
            continue;
        };
        let im = rr.render(&p.instrument, i as u64);
        let f = dir.join(format!("view-{i}.pgm"));
        std::fs::write(
            &f,
            robocal_drivers::camera::pgm::encode(im.width, im.height, &im.data),
        )?;
        println!("{}: truth {:?}", f.display(), v.shaft_lines);
        let opts = lines::LineOptions::default();
        let (edges, n) = lines::straight_edges(&im.data, im.width, im.height, &cam, &opts)
            .map_err(anyhow::Error::msg)?;
        println!("  {n} edge points, {} straight edges", edges.len());
        for e in edges.iter().take(12) {
            println!(
                "  seg [{:.1}, {:.1}, {:.1}, {:.1}] len {:.0} run {:.0} rms {:.2} contrast {:.1} pol {}",
                e.seg[0], e.seg[1], e.seg[2], e.seg[3], e.length_px, e.run_px, e.rms_px, e.contrast, e.polarity
            );
        }
        match lines::detect(&im.data, im.width, im.height, &cam, &opts) {
            Ok(d) => println!("  detected {:?} / {:?}", d.lines[0].seg, d.lines[1].seg),
            Err(e) => println!("  refused: {e}"),
        }
    }
    Ok(())
}
