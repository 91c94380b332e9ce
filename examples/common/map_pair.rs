//! The same diagnosis with and without the transmission error maps
//! ([`robocal::diagnose::transmap`]), for the real-data comparisons of
//! `examples/map_split_half.rs` and `tests/real_transmission_map.rs`.
use robocal::diagnose::{diagnose, Diagnosis, Options};
use robocal::model::KinematicModel;
use robocal::solve::obs::PoseObs;

/// `diagnose` with `opt` as given and with `transmission_map: false`, in that order.
pub fn with_and_without_maps(
    model: &KinematicModel,
    train: &[PoseObs],
    heldout: &[PoseObs],
    opt: &Options,
) -> anyhow::Result<(Diagnosis, Diagnosis)> {
    let without = Options {
        transmission_map: false,
        ..opt.clone()
    };
    Ok((
        diagnose(model, train, heldout, opt)?,
        diagnose(model, train, heldout, &without)?,
    ))
}
