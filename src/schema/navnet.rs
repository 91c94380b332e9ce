//! `extra.navchain_net` of a kinematic calibration file: seed 003's 6–n–6 correction network
//! ([`crate::navchain::nn::SeedNet`]) trained on what the calibration leaves, applied by
//! `robocal predict` on top of the calibration's own prediction.
use serde::{Deserialize, Serialize};

use crate::navchain::nn::SeedNet;

/// `format` of the block.
pub const NAVNET_FORMAT: &str = "robocal-navchain-net/1";
/// The key of the block in the calibration file's top-level object.
pub const NAVNET_KEY: &str = "navchain_net";
/// What the network reads and returns (stated in the file).
pub const NAVNET_INPUTS: &str = "in: tool pose in base x, y, z (mm), roll, pitch, yaw (deg, \
     fixed-axis x-y-z); out: dx, dy, dz (mm) added to the calibration's predicted point, 3 unused";

/// The stored network and its training figures.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavNetBlock {
    /// [`NAVNET_FORMAT`].
    pub format: String,
    /// [`NAVNET_INPUTS`].
    pub inputs: String,
    /// Hidden neurons `n`, training epochs, poses trained on.
    pub hidden: usize,
    /// Training epochs.
    pub epochs: usize,
    /// Poses trained on.
    pub train_poses: usize,
    /// Training RMS of the residual before / after the network (mm).
    pub train_rms_mm_before: f64,
    /// Training RMS after the network (mm).
    pub train_rms_mm_after: f64,
    /// Held-out RMS before / after (mm), when a held-out file was given.
    pub heldout_poses: Option<usize>,
    /// Held-out RMS before the network (mm).
    pub heldout_rms_mm_before: Option<f64>,
    /// Held-out RMS after the network (mm).
    pub heldout_rms_mm_after: Option<f64>,
    /// The weights and the standardisation (inputs in the units of `inputs`).
    pub net: SeedNet,
}

impl NavNetBlock {
    /// Checks what serde cannot: the format, the layer shapes, finite weights, positive scales.
    pub fn check(&self) -> Result<(), String> {
        if self.format != NAVNET_FORMAT {
            return Err(format!(
                "format \"{}\" (expected \"{NAVNET_FORMAT}\")",
                self.format
            ));
        }
        let n = &self.net;
        let h = n.w1.nrows();
        let shapes = [
            ("net.w1 columns", n.w1.ncols(), 6),
            ("net.b1 length", n.b1.len(), h),
            ("net.w2 rows", n.w2.nrows(), 6),
            ("net.w2 columns", n.w2.ncols(), h),
            ("net.b2 length", n.b2.len(), 6),
            ("net.x_mean length", n.x_mean.len(), 6),
            ("net.x_std length", n.x_std.len(), 6),
            ("net.y_mean length", n.y_mean.len(), 6),
            ("net.y_std length", n.y_std.len(), 6),
        ];
        for (what, got, want) in shapes {
            if got != want {
                return Err(format!(
                    "{what} is {got}, expected {want} (a 6-{h}-6 network)"
                ));
            }
        }
        let all =
            n.w1.iter()
                .chain(n.b1.iter())
                .chain(n.w2.iter())
                .chain(n.b2.iter())
                .chain(n.x_mean.iter())
                .chain(n.y_mean.iter())
                .chain(n.y_std.iter());
        if let Some(x) = all.copied().find(|x| !x.is_finite()) {
            return Err(format!("a weight or scale of net is not finite ({x})"));
        }
        if let Some(x) = n
            .x_std
            .iter()
            .copied()
            .find(|x| !(x.is_finite() && *x > 0.0))
        {
            return Err(format!("net.x_std holds {x}: the input scales must be > 0"));
        }
        Ok(())
    }
}
