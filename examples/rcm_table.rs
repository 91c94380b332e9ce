//! Issue 20 proof: RCM hand-eye (seed 002 two-step and the ML refinement) vs `AX = XB`
//! (Tsai, Park, Daniilidis) on the same simulated RCM poses, over motion ranges and image
//! noise. The world (`robocal_mocks::rcm`) holds the true camera pose and renders the shaft
//! silhouettes and the shaft marker; the estimators see only what a dataset would hold.
//!
//! `cargo run --release --example rcm_table [-- --trials N --poses K]`
use nalgebra::Isometry3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use robocal::dataset::endoscope::EndoscopeCamera;
use robocal::model::KinematicModel;
use robocal::plan::rcm::{generate, RcmPlanSpec};
use robocal::solve::rcm::{self, axxb, RcmData, RcmObs};
use robocal_mocks::rcm::{RcmCell, RcmScenario};

const METHODS: [&str; 5] = ["RCM seed", "RCM ML", "Tsai", "Park", "Daniilidis"];

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str, d: usize| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .and_then(|s| s.parse().ok())
            .unwrap_or(d)
    };
    let trials = arg("--trials", 20);
    let n_poses = arg("--poses", 20);
    let cell = RcmCell::new(RcmScenario::builtin());
    let sc = &cell.scenario;
    let cam = EndoscopeCamera {
        kind: "endoscope".into(),
        width: sc.camera.width,
        height: sc.camera.height,
        fx: sc.camera.fx,
        fy: sc.camera.fy,
        cx: sc.camera.cx,
        cy: sc.camera.cy,
        dist: sc.camera.dist,
    };
    let model = KinematicModel::preset(&sc.robot).expect("robot preset");
    let ranges: [(&str, f64, [f64; 2]); 4] = [
        ("±25° / 50–150 mm", 25.0, [50.0, 150.0]),
        ("±10° / 80–120 mm", 10.0, [80.0, 120.0]),
        ("±5° / 95–105 mm", 5.0, [95.0, 105.0]),
        ("±2° / 99–101 mm", 2.0, [99.0, 101.0]),
    ];
    let noises = [0.1, 0.5, 1.0];
    println!(
        "RCM hand-eye vs AX=XB: camera-in-base error vs truth, median over {trials} trials of {n_poses} poses \
         (scenario {}, UR5e reachability, shaft r = {} mm, marker {}x{} dots @ {} mm for AX=XB)",
        sc.name,
        sc.instrument.shaft_radius_mm,
        sc.instrument.marker_cols,
        sc.instrument.marker_rows,
        sc.instrument.marker_pitch_mm
    );
    print!("| motion range | noise px |");
    for m in METHODS {
        print!(" {m} mm / deg |");
    }
    println!();
    print!("|---|---|");
    for _ in METHODS {
        print!("---|");
    }
    println!();
    for (label, piv, ins) in ranges {
        for &sigma in &noises {
            let mut errs: Vec<Vec<(f64, f64)>> = vec![Vec::new(); METHODS.len()];
            let mut fails = vec![0usize; METHODS.len()];
            for trial in 0..trials {
                let spec = RcmPlanSpec {
                    trocar_mm: sc.trocar_mm,
                    insertion_dir: sc.insertion_dir,
                    x_hint: [0.0, 1.0, 0.0],
                    pivot_deg: piv,
                    insertion_mm: ins,
                    roll_deg: 10.0,
                    count: n_poses,
                    seed: 1000 + trial as u64,
                    shaft_length_mm: 350.0,
                };
                let poses = generate(&spec, Some(&model)).expect("plan");
                let mut rng =
                    ChaCha8Rng::seed_from_u64(7 + trial as u64 * 31 + (sigma * 100.0) as u64);
                let mut obs = Vec::new();
                let mut f_ax = Vec::new();
                let mut m_ax = Vec::new();
                for (i, p) in poses.iter().enumerate() {
                    let reported = cell.reported(&p.instrument, &mut rng);
                    let Some(v) = cell.view_noisy(&p.instrument, Some(sigma), &mut rng) else {
                        continue;
                    };
                    obs.push(RcmObs {
                        id: i as u64,
                        line: i + 2,
                        flange: reported,
                        segs: v.shaft_lines,
                    });
                    if let Some(px) = &v.marker_px {
                        let k = RcmData::new(cam.clone(), 1.0, vec![]).k;
                        if let Ok(mp) = axxb::planar_pose(&k, &cell.marker_model(), px) {
                            f_ax.push(reported);
                            m_ax.push(mp);
                        }
                    }
                }
                let data = RcmData::new(cam.clone(), sc.instrument.shaft_radius_mm, obs);
                let mut put = |k: usize, r: Option<Isometry3<f64>>| match r {
                    Some(e) => errs[k].push(rcm::pose_error(&e, &cell.camera)),
                    None => fails[k] += 1,
                };
                match rcm::calibrate(
                    &data,
                    &rcm::RcmOptions {
                        bootstrap: 0,
                        seed: 0,
                    },
                ) {
                    Ok(r) => {
                        put(0, Some(r.seed.hand_eye));
                        put(1, Some(r.ml.pose));
                    }
                    Err(_) => {
                        put(0, rcm::seed_two_step(&data).ok().map(|s| s.hand_eye));
                        put(1, None);
                    }
                }
                let (a, b) = axxb::motions(&f_ax, &m_ax);
                for (k, m) in axxb::Method::ALL.iter().enumerate() {
                    put(2 + k, axxb::solve(*m, &a, &b).ok());
                }
            }
            print!("| {label} | {sigma} |");
            for k in 0..METHODS.len() {
                if errs[k].is_empty() {
                    print!(" failed ({}/{trials}) |", fails[k]);
                    continue;
                }
                let med = |f: fn(&(f64, f64)) -> f64| {
                    let mut v: Vec<f64> = errs[k].iter().map(f).collect();
                    v.sort_by(f64::total_cmp);
                    v[v.len() / 2]
                };
                let failed = if fails[k] > 0 {
                    format!(" ({} failed)", fails[k])
                } else {
                    String::new()
                };
                print!(" {} / {}{failed} |", fmt(med(|e| e.0)), fmt(med(|e| e.1)));
            }
            println!();
        }
    }
}

fn fmt(x: f64) -> String {
    if x >= 100.0 {
        format!("{x:.0}")
    } else if x >= 10.0 {
        format!("{x:.1}")
    } else if x >= 0.1 {
        format!("{x:.2}")
    } else {
        format!("{x:.3}")
    }
}
