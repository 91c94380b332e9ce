//! The seed 001 plan on a DENSO VS060: feasible count, rejects by reason, predicted session
//! length in generated vs optimised order, and O1 with all poses and with `--select N`.
//!
//! `cargo run --release --example plan_seed001 [N]` (N defaults to 60).
use robocal::dataset::RobotBlock;
use robocal::model::KinematicModel;
use robocal::plan::{build_plan, export, observe, PlanOptions, PlanSpec};

fn main() -> anyhow::Result<()> {
    let n: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(60);
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("plans/seed001-annulus.toml");
    let spec = PlanSpec::from_file(&path)?;
    let model = KinematicModel::preset("denso-vs060")?;
    let robot = RobotBlock::named("denso-vs060");
    let all = build_plan(&spec, robot.clone(), &model, &PlanOptions::default())?;
    println!("== all feasible poses ==");
    print!("{}", export::summary_text(&all.file.summary));
    // For contrast: the first N feasible poses in generated (random) order, same scaling.
    let idm = robocal::plan::identification_model(&model, &spec)?;
    let qs: Vec<&[f64]> = all
        .feasibility
        .poses
        .iter()
        .map(|p| p.q.as_slice())
        .collect();
    let scales = observe::column_scales(&observe::stacked_jacobian(&idm, &qs));
    let first = observe::observability(&idm, &qs[..n.min(qs.len())], &scales, 1e-6);
    println!(
        "== first {n} poses in generated order: O1 = {:.4e}, cond = {:.3e} ==",
        first.o1, first.condition
    );
    let sel = build_plan(&spec, robot, &model, &PlanOptions { select: Some(n) })?;
    println!("== --select {n} ==");
    print!("{}", export::summary_text(&sel.file.summary));
    Ok(())
}
