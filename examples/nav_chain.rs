//! Figures of the navigation chain (issue 19) on the simulated operating room
//! (`robocal_mocks::navchain`): coverage of the predicted 95 % tip-error ellipsoid over
//! random rooms and targets, each link's share of the tip error, and the ICP convergence
//! rate from starts 15° / 30 mm (and 30° / 30 mm) off.
//!
//! `cargo run --release --example nav_chain [-- CHAIN_TRIALS ICP_TRIALS]` (defaults 2000, 500).
use robocal::register::icp::SurfaceIndex;
use robocal_mocks::navchain::NavNoise;

#[path = "../tests/navchain_sim.rs"]
mod sim;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let chain_trials = args.first().copied().unwrap_or(2000);
    let icp_trials = args.get(1).copied().unwrap_or(500);
    let noise = NavNoise::default();
    println!("noise: {noise:?}");
    let mut covered = 0;
    let mut var = [0.0; 5];
    let (mut pred2, mut act2) = (0.0, 0.0);
    for s in 0..chain_trials as u64 {
        let t = sim::chain_trial(100_000 + s, noise);
        covered += t.covered as usize;
        for (v, l) in var.iter_mut().zip(t.link_var) {
            *v += l;
        }
        pred2 += t.cov.trace();
        act2 += t.err.norm_squared();
    }
    let n = chain_trials as f64;
    println!(
        "chain: {chain_trials} trials: the predicted 95 % ellipsoid covers {:.1} % of the actual tip errors",
        100.0 * covered as f64 / n
    );
    println!(
        "chain: predicted RMS tip error {:.3} mm, actual {:.3} mm",
        (pred2 / n).sqrt(),
        (act2 / n).sqrt()
    );
    let tot: f64 = var.iter().sum();
    for (k, name) in robocal::navchain::LINKS.iter().enumerate() {
        println!(
            "chain: {name:<36} RMS {:.3} mm  share {:5.1} %",
            (var[k] / n).sqrt(),
            100.0 * var[k] / tot
        );
    }
    let mesh = sim::phantom();
    let idx = SurfaceIndex::new(&mesh, 1.0).expect("index");
    for (ang, shift) in [(15.0, 30.0), (30.0, 30.0)] {
        let t0 = std::time::Instant::now();
        let mut ok = 0;
        let mut worst_ok: f64 = 0.0;
        for s in 0..icp_trials as u64 {
            let (rot, pos) = sim::icp_trial(&idx, 900_000 + s, ang, shift);
            if rot < 1.0 && pos < 2.0 {
                ok += 1;
                worst_ok = worst_ok.max(pos);
            }
        }
        println!(
            "icp: start {ang} deg / {shift} mm off: {ok}/{icp_trials} = {:.1} % converged to the truth (< 1 deg, < 2 mm at every fiducial; worst converged {worst_ok:.3} mm), {:.1} s",
            100.0 * ok as f64 / icp_trials as f64,
            t0.elapsed().as_secs_f64()
        );
    }
}
