//! `robocal plan`: generate, check and export a pose plan. Plan-only: never opens a device.
//!
//! ```text
//! robocal plan --spec plans/seed001-annulus.toml --robot denso-vs060 --out PLAN.json \
//!     [--select 60] [--csv poses.csv] [--urscript plan.script] [--pacscript plan.pcs] [--json]
//! robocal plan --check PLAN.json
//! ```
use std::path::PathBuf;

use anyhow::{bail, Context};

use crate::dataset::{Dataset, RobotBlock};
use crate::model::{KinematicModel, SerialChain};
use crate::plan::{self, export, PlanFile, PlanOptions, PlanSpec};

/// Arguments of `robocal plan`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Plan specification (strict TOML, see `plans/*.toml`).
    #[arg(long, required_unless_present = "check")]
    pub spec: Option<PathBuf>,
    /// Robot preset (`denso-vs060`, `ur5e`, `ur10e`).
    #[arg(long, group = "robot_source")]
    pub robot: Option<String>,
    /// Take the robot's nominal chain from a dataset header.
    #[arg(long, group = "robot_source")]
    pub chain: Option<PathBuf>,
    /// Take the robot from a URDF file.
    #[arg(long, group = "robot_source")]
    pub urdf: Option<PathBuf>,
    /// URDF base link (default: the root).
    #[arg(long, requires = "urdf")]
    pub base_link: Option<String>,
    /// URDF tip link (default: the last link of the chain).
    #[arg(long, requires = "urdf")]
    pub tip_link: Option<String>,
    /// Write the plan (`robocal-plan/1` JSON).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Keep only N poses chosen to maximise observability (greedy D-optimal).
    #[arg(long)]
    pub select: Option<usize>,
    /// Write the pose list as CSV.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write a URScript program.
    #[arg(long)]
    pub urscript: Option<PathBuf>,
    /// Write a DENSO PacScript program.
    #[arg(long)]
    pub pacscript: Option<PathBuf>,
    /// PacScript `Speed` (percent).
    #[arg(long, default_value_t = 20.0)]
    pub pac_speed: f64,
    /// Write the text summary to a file as well.
    #[arg(long)]
    pub summary: Option<PathBuf>,
    /// Print the summary as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Validate an existing plan file and print its summary.
    #[arg(long, conflicts_with_all = ["spec", "out"])]
    pub check: Option<PathBuf>,
}

/// The URDF chain as dataset-header joints (mm, deg), so the plan file can rebuild it.
fn chain_block(sc: &SerialChain, name: &str) -> RobotBlock {
    crate::import::robot::robot_block_from_chain(sc, name)
}

fn robot_from_args(a: &Args) -> anyhow::Result<(RobotBlock, KinematicModel)> {
    let block = if let Some(name) = &a.robot {
        RobotBlock {
            model: name.clone(),
            serial: None,
            chain: None,
            flange: None,
            extra: Default::default(),
        }
    } else if let Some(path) = &a.chain {
        let ds = Dataset::load(path).with_context(|| format!("reading {}", path.display()))?;
        ds.header.robot
    } else if let Some(path) = &a.urdf {
        let xml = crate::fsio::read_to_string(path)
            .with_context(|| format!("reading {}", path.display()))?;
        let sc = SerialChain::from_urdf_str(&xml, a.base_link.as_deref(), a.tip_link.as_deref())
            .with_context(|| format!("URDF {}", path.display()))?;
        let name = path
            .file_stem()
            .map_or("urdf".into(), |s| s.to_string_lossy().into_owned());
        chain_block(&sc, &name)
    } else {
        bail!("give the robot: --robot PRESET, --chain DATASET.jsonl or --urdf FILE");
    };
    let model = KinematicModel::from_robot_block(&block).context("building the kinematic model")?;
    Ok((block, model))
}

fn write(path: &PathBuf, text: &str) -> anyhow::Result<()> {
    crate::fsio::write_atomic_ctx(path, text.as_bytes())
}

/// Run `robocal plan`.
pub fn exec(a: Args) -> anyhow::Result<()> {
    if a.select == Some(0) {
        bail!("--select 0: keep at least 1 pose (or leave --select out to keep every pose)");
    }
    if !(a.pac_speed.is_finite() && a.pac_speed > 0.0 && a.pac_speed <= 100.0) {
        bail!(
            "--pac-speed {}: a PacScript speed is a percentage in (0, 100]",
            a.pac_speed
        );
    }
    let plan = if let Some(path) = &a.check {
        let plan = PlanFile::read(path).with_context(|| format!("checking {}", path.display()))?;
        // Re-check every pose against the plan's constraints (table, envelope, joint
        // limits, self-collision): the file may have been edited since it was planned.
        let n = crate::plan::recheck::recheck(&plan, None)
            .with_context(|| format!("checking {}", path.display()))?;
        println!(
            "{}: {n} poses re-checked against the plan's constraints: all pass",
            path.display()
        );
        plan
    } else {
        let spec_path = a.spec.as_ref().context("--spec is required")?;
        let spec = PlanSpec::from_file(spec_path)
            .with_context(|| format!("reading {}", spec_path.display()))?;
        let (block, model) = robot_from_args(&a)?;
        let out = plan::build_plan(&spec, block, &model, &PlanOptions { select: a.select })?;
        out.file
    };
    if let Some(p) = &a.out {
        let text = serde_json::to_string_pretty(&plan)?;
        write(p, &text)?;
    }
    if let Some(p) = &a.csv {
        write(p, &export::to_csv(&plan)?)?;
    }
    // Script speeds and waits follow the spec's time model (slowest joint caps).
    let timing = serde_json::from_value::<PlanSpec>(plan.spec.clone())
        .map(|s| s.timing)
        .unwrap_or_default();
    let min_of = |v: &[f64]| v.iter().cloned().fold(f64::INFINITY, f64::min).to_radians();
    let (speed, accel) = (min_of(&timing.speed_deg_s), min_of(&timing.accel_deg_s2));
    let wait = timing.settle_s + timing.sample_s;
    if let Some(p) = &a.urscript {
        write(p, &export::to_urscript(&plan, speed, accel, wait))?;
    }
    if let Some(p) = &a.pacscript {
        write(p, &export::to_pacscript(&plan, a.pac_speed, wait))?;
    }
    let text = export::summary_text(&plan.summary);
    if let Some(p) = &a.summary {
        write(p, &text)?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&plan.summary)?);
    } else {
        print!("{text}");
    }
    Ok(())
}
