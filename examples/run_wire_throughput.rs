//! Acquisition throughput of the seed 001 plan over the WIRE-level dry-run cell
//! (`robocal::cell::wire_cell`): the scenario's simulators served on loopback TCP / ptys and
//! the real drivers (b-CAP, NDI, KEYENCE, UR) talking to them, on the world's virtual clock.
//! Prints poses/hour and the engine's move / settle / sample / overhead breakdown (simulated
//! seconds), plus the wall time the run took.
//!
//! `cargo run --release --example run_wire_throughput [SCENARIO.toml [PLAN.json]]`
//!
//! Default scenario: `mocks/scenarios/hospital-vs060-vega.toml` (b-CAP + Polaris Vega over
//! TCP). Without a plan file, the seed 001 plan (`plans/seed001-annulus.toml`, all feasible
//! poses) is built in-process with the tracker and marker placements of the scenario.
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context as _;
use robocal::acquire::{acquire, AcquireOptions, PlannedPose};
use robocal::dataset::{Header, Journal, RobotBlock};
use robocal::model::KinematicModel;
use robocal::plan::{build_plan, PlanFile, PlanOptions, PlanSpec};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_mocks::{Scenario, WorldHandle};

fn main() -> anyhow::Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut args = std::env::args().skip(1);
    let scen_path = args.next().map_or_else(
        || root.join("mocks/scenarios/hospital-vs060-vega.toml"),
        PathBuf::from,
    );
    let scenario =
        Scenario::load(&scen_path).with_context(|| format!("loading {}", scen_path.display()))?;
    let (robot, poses) = match args.next() {
        Some(plan) => {
            let f = PlanFile::read(Path::new(&plan))?;
            let poses = f.poses.iter().map(PlannedPose::from).collect();
            (f.robot, poses)
        }
        None => seed001(root, &scenario)?,
    };
    let model = KinematicModel::from_robot_block(&robot)?;
    let world = WorldHandle::from_scenario(&scenario)?;
    anyhow::ensure!(
        world.is_virtual(),
        "the scenario must use the virtual clock"
    );

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let opts = AcquireOptions::default();
    let (lower, upper) = model.joint_limits().into_iter().unzip();
    let limits = SafetyLimits {
        joint_lower: lower,
        joint_upper: upper,
        max_vel: opts.speed.max_vel,
        max_acc: opts.speed.max_acc,
        envelope: None,
        table: None,
        path_step: 1f64.to_radians(),
    };
    let dir = std::env::temp_dir().join(format!("robocal-wire-throughput-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut header: Header = serde_json::from_value(serde_json::json!({
        "format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}}))?;
    header.robot = robot;
    let mut journal = Journal::create(dir.join("dataset.jsonl"), &header)?;

    let wall = Instant::now();
    let (s, served) = rt.block_on(async {
        let (mut devices, _info, served) =
            robocal::cell::wire_cell(&robocal::cell::SimCell::of(&world)).await?;
        devices.arm = guard(devices.arm.clone(), limits, None);
        let s = acquire(&devices, &poses, &mut journal, &[], &opts, &mut |_| {}).await?;
        anyhow::Ok((s, served))
    })?;
    let wall_s = wall.elapsed().as_secs_f64();
    served.abort();
    // Why the fault events happened (e.g. "laser out of range" where the beam misses).
    let mut reasons = std::collections::BTreeMap::<String, usize>::new();
    for r in robocal::dataset::Dataset::load(dir.join("dataset.jsonl"))?.records {
        if let robocal::dataset::Record::Event(e) = r {
            let why = e.reason.unwrap_or_default();
            let key = why
                .split(['(', ':'])
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            *reasons.entry(format!("{}: {key}", e.what)).or_default() += 1;
        }
    }
    let _ = std::fs::remove_dir_all(&dir);

    println!("scenario {} over the wire:", scenario.name);
    for l in served.json_lines() {
        println!("  {l}");
    }
    println!(
        "poses: {} planned, {} recorded, {} skipped{}",
        s.planned,
        s.recorded,
        s.skipped.len(),
        s.aborted
            .as_ref()
            .map_or(String::new(), |a| format!(", ABORTED: {a}"))
    );
    let total = s.time.total_s();
    let pct = |x: f64| if total > 0.0 { 100.0 * x / total } else { 0.0 };
    println!(
        "simulated time {:.1} s: move {:.1} ({:.0} %), settle {:.1} ({:.0} %), sample {:.1} ({:.0} %), overhead {:.1} ({:.0} %)",
        total,
        s.time.move_s,
        pct(s.time.move_s),
        s.time.settle_s,
        pct(s.time.settle_s),
        s.time.sample_s,
        pct(s.time.sample_s),
        s.time.overhead_s,
        pct(s.time.overhead_s)
    );
    println!(
        "throughput: {:.0} poses/h (engine summary, simulated time); wall time of the run {:.1} s ({:.1} ms per pose)",
        s.poses_per_hour,
        wall_s,
        1000.0 * wall_s / (s.planned.max(1) as f64)
    );
    // On the virtual clock the drivers' round trips, the engine's computing and the fsyncs
    // take no simulated time: counting the wall time as overhead bounds what they cost.
    let handled = (s.recorded + s.skipped.len()) as f64;
    println!(
        "with the wall time counted as overhead: {:.0} poses/h ({:.1} % over the simulated cycle)",
        handled * 3600.0 / (total + wall_s),
        pct(wall_s)
    );
    println!("events: {:?} {reasons:?}", s.events);
    Ok(())
}

/// The seed 001 plan, planned for the scenario's tracker and marker placements.
fn seed001(root: &Path, scenario: &Scenario) -> anyhow::Result<(RobotBlock, Vec<PlannedPose>)> {
    let mut spec = PlanSpec::from_file(&root.join("plans/seed001-annulus.toml"))?;
    if let Some(t) = scenario.trackers.first() {
        if let Some(ts) = spec.tracker.as_mut() {
            ts.pose.xyz = t.tracker_in_base.xyz_mm;
            ts.pose.rpy = t.tracker_in_base.rpy_deg;
        }
        spec.tool.xyz = t.marker_on_flange.xyz_mm;
        spec.tool.rpy = t.marker_on_flange.rpy_deg;
    }
    let arm = scenario.arms.first().context("the scenario has no arm")?;
    let model = KinematicModel::preset(&arm.model)?;
    let robot = RobotBlock {
        model: arm.model.clone(),
        serial: None,
        chain: None,
        flange: None,
        extra: Default::default(),
    };
    let out = build_plan(&spec, robot, &model, &PlanOptions::default())?;
    let poses = out.file.poses.iter().map(PlannedPose::from).collect();
    Ok((out.file.robot, poses))
}
