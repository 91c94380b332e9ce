//! Acquisition throughput on the simulated lab cell (virtual clock): poses per hour with the
//! time breakdown (move, settle, sample, overhead) against the zero-overhead floor (the
//! moves themselves plus the tracker frames and laser readings a pose needs).
//!
//! `cargo run --example acquire_throughput [N | PLAN.json]`
//! (N random poses in front of the VS060, default 200, or the poses of a `robocal plan` file).
use std::time::Instant;

use rand::{Rng, SeedableRng};
use robocal::acquire::{acquire, AcquireOptions, PlannedPose};
use robocal::dataset::{Header, Journal};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_mocks::{Scenario, WorldHandle};

fn main() -> anyhow::Result<()> {
    let arg = std::env::args().nth(1);
    let poses: Vec<PlannedPose> = match &arg {
        Some(a) if a.ends_with(".json") => robocal::plan::PlanFile::read(std::path::Path::new(a))?
            .poses
            .iter()
            .map(PlannedPose::from)
            .collect(),
        _ => {
            let n: usize = arg.as_deref().map(str::parse).transpose()?.unwrap_or(200);
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
            let ranges = [
                (-50.0, 50.0),
                (-20.0, 50.0),
                (70.0, 120.0),
                (-60.0, 60.0),
                (-100.0, -30.0),
                (-60.0, 60.0),
            ];
            (0..n)
                .map(|i| {
                    let q = ranges
                        .iter()
                        .map(|(a, b)| rng.random_range(*a..*b))
                        .collect();
                    PlannedPose::new(i as u64, q)
                })
                .collect()
        }
    };
    let scen_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("mocks/scenarios/lab-vs060-optotrak-il600.toml");
    let scenario = Scenario::load(&scen_path)?;
    let world = WorldHandle::from_scenario(&scenario)?;
    let (mut devices, _) = robocal::cell::sim_cell(&robocal::cell::SimCell::of(&world))?;
    let opts = AcquireOptions::default();
    let limits = SafetyLimits {
        joint_lower: vec![-170f64.to_radians(); 6],
        joint_upper: vec![170f64.to_radians(); 6],
        max_vel: opts.speed.max_vel,
        max_acc: opts.speed.max_acc,
        envelope: None,
        table: None,
        path_step: 1f64.to_radians(),
    };
    devices.arm = guard(devices.arm.clone(), limits, None);
    let dir = tempfile_dir()?;
    let header: Header = serde_json::from_value(serde_json::json!({
        "format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}}))?;
    let mut journal = Journal::create(dir.join("dataset.jsonl"), &header)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let wall = Instant::now();
    let s = rt.block_on(acquire(
        &devices,
        &poses,
        &mut journal,
        &[],
        &opts,
        &mut |_| {},
    ))?;
    let wall_s = wall.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&dir);

    let rate = world.tracker_info(0).map_or(60.0, |i| i.1);
    let laser_rate = 1000.0;
    let per_pose_sample =
        opts.sample.frames as f64 / rate + opts.sample.laser_readings as f64 / laser_rate;
    let floor = s.time.move_s + s.recorded as f64 * per_pose_sample;
    let handled = (s.recorded + s.skipped.len()) as f64;
    // On hardware the engine's own computing and fsyncs add to the cycle: count the wall
    // time of this virtual-clock run as overhead too.
    let total = s.time.total_s() + wall_s;
    println!(
        "poses: {} planned, {} recorded, {} skipped",
        s.planned,
        s.recorded,
        s.skipped.len()
    );
    println!(
        "simulated time {:.1} s: move {:.1}, settle {:.1}, sample {:.1}, overhead {:.1} (+ {:.2} s engine wall time)",
        s.time.total_s(),
        s.time.move_s,
        s.time.settle_s,
        s.time.sample_s,
        s.time.overhead_s,
        wall_s
    );
    println!(
        "throughput: {:.0} poses/h (floor {:.0} poses/h: moves + {} frames @ {rate} Hz + {} laser readings)",
        handled * 3600.0 / total,
        handled * 3600.0 / floor,
        opts.sample.frames,
        opts.sample.laser_readings
    );
    println!(
        "overhead over the floor: {:.1} % (target ≤ 20 %); target ≥ 1000 poses/h: {}",
        100.0 * (total - floor) / floor,
        if handled * 3600.0 / total >= 1000.0 {
            "met"
        } else {
            "NOT met"
        }
    );
    Ok(())
}

fn tempfile_dir() -> anyhow::Result<std::path::PathBuf> {
    let d = std::env::temp_dir().join(format!("robocal-throughput-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}
