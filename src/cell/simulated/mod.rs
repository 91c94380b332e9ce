//! The simulated cell: the ONLY module of this crate that reaches the simulators
//! (`robocal_mocks`), and only through their truth-free face (`robocal_mocks::stated`): what a
//! scenario states (as a device file would: arm, limits, safety block, tracker pose and volume,
//! camera, board) and its devices as driver traits, in process or behind the real wire
//! protocols ([`wire`]). No true pose, hidden error or noise level can reach an estimator from
//! here; `the_simulators_are_reached_only_here_and_only_through_their_stated_face` (below)
//! keeps it so. The module exists only with the feature `sim` (default on; the simulators are
//! an optional dependency): a build without it has no simulators at all, and every `--sim`
//! path says so ([`super::without_simulators`]).
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use robocal_mocks::stated::SimDeviceSet;

use super::source::{
    CellInfo, CellSource, OpenCell, OpenOptions, StatedArm, StatedCamera, StatedCell,
};
use super::LiveConsent;
use crate::acquire::Devices;
use crate::plan::recheck::{CellRobot, CellSafety};
use crate::plausible::limits::CellLimit;

mod describe;
pub mod wire;

pub use describe::describe_scenario;
pub use robocal_mocks::stated::{Bind, Endpoint, Only, Served, SimCell, StatedScenario};
pub use wire::wire_cell;

/// The simulated cell of the scenario file at `path`, on a virtual or the wall clock.
pub fn open_world(path: &Path, virtual_clock: bool) -> anyhow::Result<SimCell> {
    SimCell::open(path, virtual_clock).with_context(|| {
        format!(
            "building the world of {}{}",
            path.display(),
            other_kind(path)
        )
    })
}

/// What the scenario file at `path` states.
pub fn stated_scenario(path: &Path) -> anyhow::Result<StatedScenario> {
    StatedScenario::load(path)
        .with_context(|| format!("reading {}{}", path.display(), other_kind(path)))
}

/// ": this is a calibration file …, not a scenario" when the file at `path` (a regular file
/// robocal can read) is another robocal file; empty otherwise.
fn other_kind(path: &Path) -> String {
    crate::fsio::read_to_string(path)
        .ok()
        .and_then(|t| {
            crate::schema::kind::toml_reader_hint(&t, crate::schema::kind::TomlKind::Scenario)
        })
        .map_or_else(String::new, |h| format!(": {h}"))
}

/// The scenario file at `path` cut to arm `arm` (its trackers, lasers and cameras) and to the
/// devices `only` keeps, as the TOML a single-arm session runs on.
pub fn one_arm_scenario(path: &Path, arm: &str, only: Only) -> anyhow::Result<String> {
    robocal_mocks::stated::one_arm_scenario_toml(path, arm, only)
        .with_context(|| format!("writing the session's scenario from {}", path.display()))
}

/// What the header records about a simulated cell.
fn info(cell: &SimCell) -> CellInfo {
    let s = cell.stated();
    CellInfo {
        serial: cell.arm_serial(),
        tracker_kind: s.trackers.first().map(|t| t.kind.clone()),
        range_kind: s.lasers.first().map(|l| l.kind.clone()),
    }
}

/// The devices of a cell with the cell's clock.
fn devices(cell: &SimCell, set: SimDeviceSet) -> Devices {
    Devices {
        arm: set.arm,
        tracker: set.tracker,
        range: set.range,
        clock: cell.clock(),
        camera: set.camera,
    }
}

/// The in-process simulated devices of a cell: its first arm, tracker, laser and camera, and
/// its clock. The arm is NOT yet wrapped in the safety decorators. (`robocal run` drops the
/// camera when the run does not record images.)
pub fn sim_cell(cell: &SimCell) -> anyhow::Result<(Devices, CellInfo)> {
    let Some(set) = cell.in_process() else {
        bail!("scenario {:?} has no arm", cell.stated().name);
    };
    Ok((devices(cell, set), info(cell)))
}

/// Serves every device of the scenario file at `path` over its real wire protocol
/// (`robocal sim serve`); keep the result alive, [`Served::abort`] stops the servers.
pub async fn serve(
    path: &Path,
    host: std::net::IpAddr,
    standard_ports: bool,
    virtual_clock: bool,
) -> anyhow::Result<Served> {
    let cell = open_world(path, virtual_clock)?;
    let bind = Bind {
        host,
        standard_ports,
    };
    Ok(cell.serve(&bind).await?)
}

/// A scenario file as a run's cell.
#[derive(Debug, Clone)]
pub struct ScenarioCell {
    path: PathBuf,
    opts: OpenOptions,
}

impl ScenarioCell {
    /// The cell of the scenario file at `path`.
    pub fn new(path: &Path, opts: OpenOptions) -> Self {
        Self {
            path: path.to_path_buf(),
            opts,
        }
    }
}

/// The stated arm `a` of the scenario file `path`.
fn stated_arm(path: &Path, a: &robocal_mocks::stated::StatedArm) -> StatedArm {
    let src = |k: &str| format!("{}: arm \"{}\" motion.{k}", path.display(), a.name);
    StatedArm {
        robot: CellRobot {
            source: format!("{}: arm \"{}\"", path.display(), a.name),
            model: Some(a.model.clone()),
            safety: a.safety.as_ref().map(|s| CellSafety {
                table_z_mm: s.table_z_mm,
                table_clearance_mm: s.table_clearance_mm.unwrap_or(0.0),
                envelope: s.envelope.clone(),
                joint_limits_deg: None,
            }),
        },
        vel: Some(CellLimit {
            value: a.max_vel_deg_s,
            source: src("max_vel_deg_s"),
        }),
        acc: Some(CellLimit {
            value: a.max_acc_deg_s2,
            source: src("max_acc_deg_s2"),
        }),
    }
}

/// The first camera of a scenario and its board.
fn stated_camera(s: &StatedScenario) -> Option<StatedCamera> {
    let c = s.cameras.first()?;
    let b = s.board.as_ref();
    Some(StatedCamera {
        name: c.name.clone(),
        header: crate::dataset::CameraHeader {
            kind: "mono".into(),
            width: c.width,
            height: c.height,
            name: Some(c.name.clone()),
            mount: Some(if c.arm.is_some() { "flange" } else { "base" }.into()),
        },
        target: b.map(|b| crate::dataset::TargetHeader {
            kind: if b.charuco.is_some() {
                "charuco"
            } else {
                "chessboard"
            }
            .into(),
            cols: b.cols.saturating_sub(1),
            rows: b.rows.saturating_sub(1),
            square_mm: b.square_mm,
            marker_mm: b.charuco.as_ref().map(|m| m.0),
            dictionary: b.charuco.as_ref().map(|m| m.1.clone()),
        }),
        detect: b
            .filter(|b| b.cols >= 3 && b.rows >= 3)
            // OpenCV's chessboard detector cannot label a ChArUco board's corners:
            // ChArUco images are detected by `calibrate camera` (with their ids).
            .filter(|b| b.charuco.is_none())
            .map(|b| (b.cols - 1, b.rows - 1)),
    })
}

impl CellSource for ScenarioCell {
    fn stated(&self, arm: Option<&str>) -> anyhow::Result<StatedCell> {
        let s = stated_scenario(&self.path)?;
        let Some(a) = s.arm(arm) else {
            bail!(
                "{}: the scenario has no [[arm]]{}",
                self.path.display(),
                arm.map_or_else(String::new, |n| format!(" named {n:?}"))
            );
        };
        Ok(StatedCell {
            arm: stated_arm(&self.path, a),
            camera: stated_camera(&s),
        })
    }

    fn open(
        &self,
        rt: &tokio::runtime::Runtime,
        _consent: Option<&LiveConsent>,
    ) -> anyhow::Result<OpenCell> {
        let world = open_world(&self.path, self.opts.virtual_clock)?;
        let at = || format!("{}", self.path.display());
        if self.opts.in_process {
            let (devices, info) = sim_cell(&world).with_context(at)?;
            return Ok(OpenCell {
                devices,
                info,
                stop: None,
            });
        }
        // The dry run proper: simulators serve the real protocols on loopback / ptys and the
        // real drivers connect to them.
        let (devices, info, served) = rt.block_on(wire_cell(&world)).with_context(at)?;
        Ok(OpenCell {
            devices,
            info,
            stop: Some(Box::new(move || served.abort())),
        })
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// The items of the simulators' truth-free face this module may use.
    const FACE: [&str; 13] = [
        "Bind",
        "Endpoint",
        "Only",
        "Protocol",
        "Served",
        "SimCell",
        "SimDeviceSet",
        "StatedArm",
        "StatedPose",
        "StatedScenario",
        "one_arm_scenario_toml",
        "stated",
        "",
    ];

    /// Every `.rs` file under `dir`, with its path.
    fn sources(dir: &Path, out: &mut Vec<(std::path::PathBuf, String)>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                sources(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).unwrap();
                out.push((p, text));
            }
        }
    }

    /// The items named after each `robocal_mocks` in `text`: `a::b::C` gives `a::b::C`,
    /// `a::{B, C}` gives `a::B` and `a::C`.
    fn named(text: &str) -> Vec<String> {
        let mut out = Vec::new();
        for (i, _) in text.match_indices("robocal_mocks") {
            let rest = &text[i..];
            let end = rest
                .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                .unwrap_or(rest.len());
            let path = &rest[..end];
            if rest[end..].starts_with('{') {
                let group = &rest[end + 1..rest[end..].find('}').map_or(rest.len(), |j| end + j)];
                out.extend(group.split(',').map(|g| format!("{path}{}", g.trim())));
            } else {
                out.push(path.trim_end_matches(':').to_string());
            }
        }
        out
    }

    /// The boundary between the estimators and the simulated world is structural: no file of
    /// `src/` outside this module names the simulators' crate, and this module names only the
    /// listed items of its truth-free face (`robocal_mocks::stated`), never the world, its
    /// control or its truth.
    #[test]
    fn the_simulators_are_reached_only_here_and_only_through_their_stated_face() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let here = root.join("src/cell/simulated");
        let mut files = Vec::new();
        sources(&root.join("src"), &mut files);
        assert!(files.len() > 50, "the scan sees the sources");
        let mut outside = Vec::new();
        let mut inside = 0;
        for (p, text) in &files {
            let uses = named(text);
            if !p.starts_with(&here) {
                if !uses.is_empty() {
                    outside.push(p.display().to_string());
                }
                continue;
            }
            for u in uses {
                inside += 1;
                let item = u
                    .strip_prefix("robocal_mocks::stated::")
                    .or_else(|| (u == "robocal_mocks::stated").then_some("stated"))
                    .or_else(|| (u == "robocal_mocks").then_some(""));
                assert!(
                    item.is_some_and(|i| FACE.contains(&i)),
                    "{}: `{u}` is not an item of the stated face",
                    p.display()
                );
            }
        }
        assert!(
            outside.is_empty(),
            "only src/cell/simulated/ may name robocal_mocks: {outside:?}"
        );
        assert!(inside >= 5, "the simulated cell reaches the simulators");
        // The scan itself: a path into the world, and a group with one, are seen.
        let m = ["robocal", "_mocks"].concat();
        assert_eq!(
            named(&format!("use {m}::world::WorldHandle;")),
            [format!("{m}::world::WorldHandle")]
        );
        assert_eq!(
            named(&format!("use {m}::stated::{{SimCell, x::Truth}};")),
            [
                format!("{m}::stated::SimCell"),
                format!("{m}::stated::x::Truth")
            ]
        );
        // The face itself hands out no truth: no public item or field names the world, its
        // control, its truth, errors, effects or noise; the world handle is private.
        let face = std::fs::read_to_string(root.join("mocks/src/stated.rs")).unwrap();
        for l in face.lines().filter(|l| l.trim_start().starts_with("pub ")) {
            // A function may take a world built elsewhere (a test keeps it to inject faults);
            // what it returns is checked.
            let l = match l.split_once("fn ") {
                Some((_, f)) => {
                    let name = f.split('(').next().unwrap_or("");
                    format!("{name} {}", f.split_once("->").map_or("", |r| r.1))
                }
                None => l.to_string(),
            };
            for banned in [
                "WorldHandle",
                "Truth",
                "Control",
                "errors",
                "effects",
                "noise",
            ] {
                assert!(!l.contains(banned), "the stated face exposes {banned}: {l}");
            }
        }
        assert!(face.contains("    world: WorldHandle,") && !face.contains("pub world"));
    }

    /// The simulators are not even in the estimators' build: `robocal-mocks` is an optional
    /// dependency behind the feature `sim` (a dev-dependency for the tests), this module is
    /// compiled only with it, and CI builds the library and the binary without it.
    #[test]
    fn the_simulators_are_an_optional_dependency_behind_the_feature_sim() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let manifest: toml::Table =
            toml::from_str(&std::fs::read_to_string(root.join("Cargo.toml")).unwrap()).unwrap();
        let mocks = &manifest["dependencies"]["robocal-mocks"];
        assert_eq!(
            mocks.get("optional").and_then(|v| v.as_bool()),
            Some(true),
            "robocal-mocks must be an optional dependency: {mocks}"
        );
        let features = &manifest["features"];
        assert_eq!(
            features["sim"].as_array().unwrap(),
            &vec![toml::Value::from("dep:robocal-mocks")]
        );
        assert!(
            features["default"]
                .as_array()
                .unwrap()
                .contains(&toml::Value::from("sim")),
            "`sim` is a default feature"
        );
        // Every other feature reaches the mocks only when `sim` is on (`robocal-mocks?/...`).
        for (name, list) in features.as_table().unwrap() {
            for f in list.as_array().unwrap().iter().filter_map(|v| v.as_str()) {
                assert!(
                    name == "sim" || !f.starts_with("robocal-mocks/"),
                    "feature {name} turns the simulators on: {f}"
                );
            }
        }
        let cell = std::fs::read_to_string(root.join("src/cell/mod.rs")).unwrap();
        assert!(
            cell.contains("#[cfg(feature = \"sim\")]\npub mod simulated;"),
            "src/cell/mod.rs compiles `simulated` only with the feature `sim`"
        );
        let ci = std::fs::read_to_string(root.join(".ci/run")).unwrap();
        assert!(
            ci.lines().any(|l| !l.trim_start().starts_with('#')
                && l.contains("-p robocal --no-default-features --lib --bins")),
            ".ci/run builds the library and the binary without the simulators"
        );
    }
}
