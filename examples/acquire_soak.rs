//! Soak test of the acquisition engine over the wire (issue 14): POSES poses on the virtual
//! clock through the real drivers against the simulators' protocol servers, with every wire
//! fault of the simulators (link drop, delay, error reply, garbage, bad CRC, truncated reply,
//! silence) plus protective stops injected at random between poses. Each invocation either
//! completes or stops safely (aborted, resumable); the soak resumes until the plan is done.
//!
//! Checked: the same poses run once without faults and once with them record the same pose ids
//! (no pose lost to a fault); every fault the client must see as an error (link drop, bad CRC,
//! truncated or refused reply, protective stop) is followed by at least one event (faults are
//! injected one at a time so each is matched with its events; a delay or silence within the
//! reply deadline and garbage the decoder skips may pass without one, and are counted);
//! every record an invocation reported is in the final journal (nothing lost), the
//! journal loads with the strict reader (no duplicate ids, no torn line), every planned pose
//! is recorded or skipped, faults leave `fault` / `retry` / `pause` / `resume` events.
//!
//! `cargo run --release --example acquire_soak [POSES] [FAULT_PROB] [SEED] [lab|hospital|both]`
//! (default 2000 poses, half on the lab cell — b-CAP arm, DL-RS1A laser — half on the hospital
//! cell — b-CAP arm, NDI Vega over TCP —, fault probability 0.15 per pose, seed 14).
use std::collections::BTreeSet;
use std::path::Path;
use std::time::Instant;

use rand::{Rng, SeedableRng};
use robocal::acquire::{acquire, AcquireOptions, PlannedPose};
use robocal::cell::wire_cell;
use robocal::dataset::{read_dataset, Header, Journal, Record};
use robocal_drivers::safety::{guard, SafetyLimits};
use robocal_mocks::scenario::ClockMode;
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};

/// Totals of one scenario's soak.
#[derive(Default, Debug)]
pub struct Tally {
    pub poses: usize,
    pub injected: usize,
    pub consumed: usize,
    pub stops: usize,
    pub invocations: usize,
    pub aborted: usize,
    pub recorded: usize,
    pub skipped: usize,
    pub events: std::collections::BTreeMap<String, usize>,
    pub skip_reasons: std::collections::BTreeMap<String, usize>,
    /// Per fault kind: (consumed, consumed and followed by at least one event).
    pub consumed_by_kind: std::collections::BTreeMap<&'static str, (usize, usize)>,
    /// Faults that must surface as an error but left no event.
    pub silent: Vec<String>,
    /// The recorded pose ids.
    pub ids: BTreeSet<u64>,
    pub wall_s: f64,
    pub sim_s: f64,
}

/// The fault in flight: injected, not yet matched with its events.
struct Outstanding {
    /// The wire device it was queued on (`None`: a protective stop of the arm).
    device: Option<String>,
    kind: &'static str,
    /// Whether the client must see it as an error (a link drop, a bad CRC, a truncated or
    /// refused reply, a protective stop); a short delay or silence within the reply deadline,
    /// or garbage the decoder skips, is absorbed without one.
    must_error: bool,
    /// Fault-related events in the journal when it was injected.
    events_at: usize,
}

fn classify(f: &Fault) -> (&'static str, bool) {
    match f {
        Fault::DropLink => ("drop-link", true),
        Fault::Delay { .. } => ("delay", false),
        Fault::ErrorReply { .. } => ("error-reply", true),
        Fault::Garbage { .. } => ("garbage", false),
        Fault::BadCrc => ("bad-crc", true),
        Fault::Truncated => ("truncated", true),
        Fault::Silence { .. } => ("silence", false),
        _ => ("other", false),
    }
}

/// Reads the journal's new complete lines as the run appends them and counts the events a
/// fault can cause (everything but notes and the tracker's own "marker not visible" retries
/// and skips, which happen without any fault).
#[derive(Default)]
struct JournalTail {
    offset: u64,
    fault_events: usize,
}

impl JournalTail {
    fn read_new(&mut self, path: &Path) {
        use std::io::{Read, Seek, SeekFrom};
        let Ok(mut f) = std::fs::File::open(path) else {
            return;
        };
        let mut buf = Vec::new();
        if f.seek(SeekFrom::Start(self.offset)).is_err() || f.read_to_end(&mut buf).is_err() {
            return;
        }
        let Some(end) = buf.iter().rposition(|&b| b == b'\n') else {
            return;
        };
        for line in buf[..end].split(|&b| b == b'\n') {
            let Ok(v) = serde_json::from_slice::<serde_json::Value>(line) else {
                continue;
            };
            if v["kind"] != "event" || v["what"] == "note" {
                continue;
            }
            let reason = v["reason"].as_str().unwrap_or("");
            if reason.contains("not visible") {
                continue;
            }
            self.fault_events += 1;
        }
        self.offset += end as u64 + 1;
    }
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

/// Soak `n` random poses on the scenario `file` (relative to the crate) with fault probability
/// `prob` per pose; every check of the module docs is an error when it fails.
pub fn soak(file: &str, n: usize, prob: f64, seed: u64) -> anyhow::Result<Tally> {
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
    let (mut devices, _info, served) =
        rt.block_on(wire_cell(&robocal::cell::SimCell::of(&world)))?;
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
    // One fault outstanding at a time, so each can be matched with the events it caused.
    let mut outstanding: Option<Outstanding> = None;
    let mut log = JournalTail::default();
    loop {
        tally.invocations += 1;
        anyhow::ensure!(tally.invocations < 200, "the soak never completed");
        let (mut journal, existing, warnings) = Journal::open_or_create(&jpath, &header)?;
        anyhow::ensure!(warnings.is_empty(), "{warnings:?}");
        let mut inject = |p: &robocal::acquire::Progress| {
            if p.ok {
                reported.insert(p.id);
            }
            log.read_new(&jpath);
            if let Some(o) = &outstanding {
                let consumed = o.device.as_ref().is_none_or(|d| ctl.pending_faults(d) == 0);
                if !consumed {
                    return;
                }
                let evented = log.fault_events > o.events_at;
                tally.consumed_by_kind.entry(o.kind).or_default().0 += 1;
                if evented {
                    tally.consumed_by_kind.entry(o.kind).or_default().1 += 1;
                } else if o.must_error {
                    tally.silent.push(format!("{} on {:?}", o.kind, o.device));
                }
                outstanding = None;
            }
            if rng.random_bool(prob) {
                if rng.random_bool(0.1) {
                    ctl.protective_stop(0);
                    tally.stops += 1;
                    outstanding = Some(Outstanding {
                        device: None,
                        kind: "protective-stop",
                        must_error: true,
                        events_at: log.fault_events,
                    });
                } else {
                    let (name, kind) = &wire[rng.random_range(0..wire.len())];
                    let f = fault(&mut rng, kind);
                    let (label, must_error) = classify(&f);
                    ctl.inject(name, f);
                    tally.injected += 1;
                    outstanding = Some(Outstanding {
                        device: Some(name.clone()),
                        kind: label,
                        must_error,
                        events_at: log.fault_events,
                    });
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
        if std::env::var_os("ROBOCAL_SOAK_VERBOSE").is_some() {
            eprintln!(
                "invocation {}: recorded {} (+{}), remaining {}, skipped {}, aborted {:?}",
                tally.invocations,
                s.recorded,
                s.recorded_now,
                s.remaining,
                s.skipped.len(),
                s.aborted
            );
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
                let reason = e.reason.as_deref().unwrap_or("?");
                let class = if std::env::var_os("ROBOCAL_SOAK_VERBOSE").is_some() {
                    reason.chars().take(400).collect()
                } else {
                    reason.split(':').next().unwrap_or(reason).to_string()
                };
                *tally.skip_reasons.entry(class).or_default() += 1;
            }
            _ => {}
        }
    }
    tally.ids = ids.clone();
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
    anyhow::ensure!(
        tally.silent.is_empty(),
        "faults that must surface as an error left no event: {:?}",
        tally.silent
    );
    Ok(tally)
}

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(2000);
    let prob: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(0.15);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(14);
    let only = args.next().unwrap_or_else(|| "both".into());
    anyhow::ensure!(
        ["both", "lab", "hospital"].contains(&only.as_str()),
        "the fourth argument is lab, hospital or both, not {only:?}"
    );
    let cells = [
        ("lab", "mocks/scenarios/lab-vs060-optotrak-il600.toml"),
        ("hospital", "mocks/scenarios/hospital-vs060-vega.toml"),
    ];
    let chosen: Vec<_> = cells
        .iter()
        .filter(|(name, _)| only == "both" || only == *name)
        .collect();
    let mut total = Tally::default();
    for (k, (_, file)) in chosen.iter().enumerate() {
        let part = if chosen.len() == 1 {
            n
        } else {
            n / 2 + if k == 0 { n % 2 } else { 0 }
        };
        // The same poses without any fault: which poses the cell records undisturbed.
        let calm = soak(file, part, 0.0, seed + k as u64)?;
        let t = soak(file, part, prob, seed + k as u64)?;
        let lost: Vec<_> = calm.ids.difference(&t.ids).collect();
        let gained: Vec<_> = t.ids.difference(&calm.ids).collect();
        println!(
            "{file}: without faults {} of {} poses recorded; with faults {}: {} poses lost to \
             faults, {} recorded only with faults",
            calm.recorded,
            part,
            t.recorded,
            lost.len(),
            gained.len()
        );

        println!(
            "{file}: {} poses, {} recorded, {} skipped; {} wire faults injected ({} consumed), \
             {} protective stops; {} invocations ({} ended aborted, resumed); events {:?}; \
             skip reasons {:?}; faults consumed (kind: consumed, followed by an event) {:?}; \
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
            t.skip_reasons,
            t.consumed_by_kind,
            t.sim_s,
            t.wall_s
        );
        anyhow::ensure!(
            lost.is_empty(),
            "faults cost poses the undisturbed run records: {lost:?}"
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
