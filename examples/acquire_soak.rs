//! Soak test of the acquisition engine over the wire (issue 14): POSES poses on the virtual
//! clock through the real drivers against the simulators' protocol servers, with every wire
//! fault of the simulators (link drop, delay, error reply, garbage, bad CRC, truncated reply,
//! silence) plus protective stops injected at random between poses. Each invocation either
//! completes or stops safely (aborted, resumable); the soak resumes until the plan is done.
//!
//! Checked: every record an invocation reported is in the final journal (nothing lost), the
//! journal loads with the strict reader (no duplicate ids, no torn line), every planned pose
//! is recorded or skipped, faults leave `fault` / `retry` / `pause` / `resume` events.
//!
//! `cargo run --release --example acquire_soak [POSES] [FAULT_PROB] [SEED]`
//! (default 2000 poses, half on the lab cell — b-CAP arm, DL-RS1A laser — half on the hospital
//! cell — b-CAP arm, NDI Vega over TCP —, fault probability 0.15 per pose, seed 14).
use std::collections::BTreeSet;
use std::path::Path;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use robocal::acquire::{acquire, AcquireOptions, PlannedPose};
use robocal::cli::wire_cell::wire_cell;
use robocal::dataset::{read_dataset, Header, Journal, Record};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_mocks::scenario::ClockMode;
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};

/// Totals of one scenario's soak.
#[derive(Default, Debug)]
struct Tally {
    poses: usize,
    injected: usize,
    consumed: usize,
    stops: usize,
    invocations: usize,
    aborted: usize,
    recorded: usize,
    skipped: usize,
    events: std::collections::BTreeMap<String, usize>,
    wall_s: f64,
    sim_s: f64,
}

fn random_poses(n: usize, rng: &mut rand_chacha::ChaCha8Rng) -> Vec<PlannedPose> {
    let ranges = [
        (-40.0, 40.0),
        (-10.0, 40.0),
        (75.0, 115.0),
        (-50.0, 50.0),
        (-90.0, -35.0),
        (-50.0, 50.0),
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

fn fault(rng: &mut rand_chacha::ChaCha8Rng, device_kind: &str) -> Fault {
    match rng.random_range(0..7) {
        0 => Fault::DropLink,
        1 => Fault::Delay {
            secs: rng.random_range(0.05..0.5),
        },
        2 => Fault::ErrorReply {
            code: match device_kind {
                "arm" => -2147467259, // 0x80004005 E_FAIL
                _ => 1,
            },
        },
        3 => Fault::Garbage {
            bytes: (0..rng.random_range(1..24))
                .map(|_| rng.random::<u8>())
                .collect(),
        },
        4 => Fault::BadCrc,
        5 => Fault::Truncated,
        _ => Fault::Silence {
            secs: rng.random_range(0.5..4.0),
        },
    }
}

fn soak(file: &str, n: usize, prob: f64, seed: u64) -> anyhow::Result<Tally> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(file);
    let mut scenario = Scenario::load(&path)?;
    scenario.clock = ClockMode::Virtual;
    let world = WorldHandle::from_scenario(&scenario)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let poses = random_poses(n, &mut rng);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let (mut devices, _info, served) = rt.block_on(wire_cell(&world))?;
    let opts = AcquireOptions {
        sample: robocal::acquire::SampleOptions {
            frames: 10,
            min_frames: 4,
            ..Default::default()
        },
        ..AcquireOptions::default()
    };
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
    // Wire devices: the arm, and the tracker / laser when they are served over a wire.
    let mut wire: Vec<(String, &str)> = vec![(scenario.arms[0].name.clone(), "arm")];
    let unavailable: Vec<String> = served.unavailable.iter().map(|u| u.0.clone()).collect();
    for t in &scenario.trackers {
        if !unavailable.contains(&t.name) {
            wire.push((t.name.clone(), "tracker"));
        }
    }
    for l in &scenario.lasers {
        wire.push((l.name.clone(), "laser"));
    }
    let dir = tempfile::tempdir()?;
    let jpath = dir.path().join("dataset.jsonl");
    let header: Header = serde_json::from_value(serde_json::json!({
        "format": "robocal-dataset/1", "robot": {"model": "denso-vs060"}}))?;
    let mut tally = Tally {
        poses: n,
        ..Tally::default()
    };
    let mut reported: BTreeSet<u64> = BTreeSet::new();
    let wall = Instant::now();
    let t0 = world.now();
    let ctl = world.control();
    loop {
        tally.invocations += 1;
        anyhow::ensure!(tally.invocations < 200, "the soak never completed");
        let (mut journal, existing, warnings) = Journal::open_or_create(&jpath, &header)?;
        anyhow::ensure!(warnings.is_empty(), "{warnings:?}");
        let mut inject = |p: &robocal::acquire::Progress| {
            if p.ok {
                reported.insert(p.id);
            }
            if rng.random_bool(prob) {
                if rng.random_bool(0.1) {
                    ctl.protective_stop(0);
                    tally.stops += 1;
                } else {
                    let (name, kind) = &wire[rng.random_range(0..wire.len())];
                    let f = fault(&mut rng, kind);
                    ctl.inject(name, f);
                    tally.injected += 1;
                }
            }
        };
        let s = rt.block_on(acquire(
            &devices,
            &poses,
            &mut journal,
            &existing,
            &opts,
            &mut inject,
        ))?;
        if s.aborted.is_some() {
            tally.aborted += 1;
        }
        if s.remaining == 0 {
            tally.recorded = s.recorded;
            tally.skipped = s.skipped.len();
            tally.events = s.events.clone();
            break;
        }
    }
    tally.wall_s = wall.elapsed().as_secs_f64();
    tally.sim_s = world.now() - t0;
    let pending: usize = wire.iter().map(|(n, _)| ctl.pending_faults(n)).sum();
    tally.consumed = tally.injected - pending;
    served.abort();
    // The journal: strict reader, nothing reported lost, every planned pose accounted for.
    let loaded = read_dataset(&jpath)?;
    anyhow::ensure!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let mut ids = BTreeSet::new();
    let mut skipped = BTreeSet::new();
    for r in &loaded.dataset.records {
        match r {
            Record::Pose(p) => {
                anyhow::ensure!(ids.insert(p.id), "pose {} twice", p.id);
            }
            Record::Event(e) if e.what == "skip" => {
                skipped.extend(e.id);
            }
            _ => {}
        }
    }
    let lost: Vec<_> = reported.difference(&ids).collect();
    anyhow::ensure!(lost.is_empty(), "records reported but lost: {lost:?}");
    anyhow::ensure!(
        ids.len() == tally.recorded,
        "{} records, summary {}",
        ids.len(),
        tally.recorded
    );
    let all: BTreeSet<u64> = ids.union(&skipped).copied().collect();
    anyhow::ensure!(all.len() == n, "{} of {n} poses accounted for", all.len());
    let fault_events: usize = ["fault", "pause"]
        .iter()
        .map(|k| tally.events.get(*k).copied().unwrap_or(0))
        .sum();
    anyhow::ensure!(
        tally.consumed + tally.stops == 0 || fault_events > 0,
        "faults but no fault events"
    );
    Ok(tally)
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(2000);
    let prob: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(0.15);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(14);
    let mut total = Tally::default();
    for (k, file) in [
        "mocks/scenarios/lab-vs060-optotrak-il600.toml",
        "mocks/scenarios/hospital-vs060-vega.toml",
    ]
    .iter()
    .enumerate()
    {
        let part = n / 2 + if k == 0 { n % 2 } else { 0 };
        let t = soak(file, part, prob, seed + k as u64)?;
        println!(
            "{file}: {} poses, {} recorded, {} skipped; {} wire faults injected ({} consumed), \
             {} protective stops; {} invocations ({} ended aborted, resumed); events {:?}; \
             {:.0} s simulated in {:.1} s wall",
            t.poses,
            t.recorded,
            t.skipped,
            t.injected,
            t.consumed,
            t.stops,
            t.invocations,
            t.aborted,
            t.events,
            t.sim_s,
            t.wall_s
        );
        total.poses += t.poses;
        total.recorded += t.recorded;
        total.skipped += t.skipped;
        total.injected += t.injected;
        total.consumed += t.consumed;
        total.stops += t.stops;
        total.aborted += t.aborted;
        total.invocations += t.invocations;
    }
    println!(
        "soak: {} poses, {} recorded, {} skipped, {} wire faults injected ({} consumed) + {} \
         protective stops, {} invocations ({} aborted safely and resumed): journal loads, \
         nothing recorded lost",
        total.poses,
        total.recorded,
        total.skipped,
        total.injected,
        total.consumed,
        total.stops,
        total.invocations,
        total.aborted
    );
    anyhow::ensure!(
        total.injected + total.stops >= 200 || n < 2000,
        "fewer than 200 faults injected"
    );
    Ok(())
}
