//! Offline acquisition synthesiser for solver tests.
//!
//! Drives a virtual-clock world exactly like an acquisition would (move, settle, average
//! `frames_per_pose` tracker frames, wait for the next slot) and writes what it would have
//! recorded as `robocal-dataset/1` JSONL (train and validation files), the noise-free truth of the
//! held-out poses (`id,x_mm,y_mm,z_mm`, marker origin in the tracker frame) and a case JSON with
//! the true parameters — the same layout as `tests/data/kin-*`.
//!
//! Pose records carry, besides the standard fields, `approach` (sign of the last motion of each
//! joint, ±1) and, when thermal drift is on, `temp_c`.

use crate::world::chain::UrdfChain;
use crate::world::WorldHandle;
use nalgebra::{Isometry3, UnitQuaternion, Vector3, Vector4};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use robocal_drivers::{MoveSpeed, ToolStatus};
use serde_json::{json, Value};

/// Why synthesis failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SynthError {
    /// The world must run on virtual time.
    #[error("the synthesiser needs a virtual-clock world")]
    NotVirtual,
    /// No such arm / tracker / laser.
    #[error("no {0} in the world")]
    NoDevice(&'static str),
    /// Could not find enough poses where the marker is visible.
    #[error("found only {found} visible poses out of {wanted} after {tries} tries")]
    NoPoses {
        /// Found.
        found: usize,
        /// Wanted.
        wanted: usize,
        /// Attempts.
        tries: usize,
    },
    /// A move was refused.
    #[error("move refused: {0}")]
    Move(#[from] crate::world::WorldError),
}

/// What to synthesise.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthConfig {
    /// Number of training poses.
    pub n_train: usize,
    /// Number of held-out (validation) poses, interleaved every `heldout_every`-th pose.
    pub n_heldout: usize,
    /// Seed of the pose sampling (the world's own seed draws errors and noise).
    pub seed: u64,
    /// Tracker frames averaged per pose.
    pub frames_per_pose: u32,
    /// Nominal time from one pose to the next (s); ±10 % jitter.
    pub pose_period_s: f64,
    /// Every n-th pose goes to validation.
    pub heldout_every: usize,
    /// Joint sampling box (deg, per joint); `None` = the model's default region.
    pub region_deg: Option<Vec<[f64; 2]>>,
    /// Move speed.
    pub speed: MoveSpeed,
    /// `created` timestamp of the header.
    pub created: String,
    /// Arm index.
    pub arm: usize,
    /// Tracker index.
    pub tracker: usize,
    /// Measure on the fly instead of stop-and-measure: one tracker frame taken at this
    /// fraction (0–1) of each move, with the joint state of the same instant, and the
    /// records carry the joint velocities `qd` (deg/s). `None`: settle, then average
    /// `frames_per_pose` frames.
    pub in_motion: Option<f64>,
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            n_train: 500,
            n_heldout: 150,
            seed: 1,
            frames_per_pose: 30,
            pose_period_s: 9.0,
            heldout_every: 4,
            region_deg: None,
            speed: MoveSpeed {
                max_vel: 90f64.to_radians(),
                max_acc: 180f64.to_radians(),
            },
            created: "2026-11-21T08:00:00Z".into(),
            arm: 0,
            tracker: 0,
            in_motion: None,
        }
    }
}

/// The synthesised files.
#[derive(Debug, Clone, PartialEq)]
pub struct SynthOutput {
    /// `robocal-dataset/1` with `group: train` poses.
    pub train_jsonl: String,
    /// `robocal-dataset/1` with `group: validation` poses.
    pub heldout_jsonl: String,
    /// `id,x_mm,y_mm,z_mm` noise-free marker origin (tracker frame) per held-out pose.
    pub truth_csv: String,
    /// True parameters.
    pub case_json: String,
}

/// Default sampling region (deg) per model: a cylindrical-annulus-like region in front of the
/// arm (seed 001 style) for the VS060, a similar one for UR arms.
pub fn default_region_deg(model: &str) -> Vec<[f64; 2]> {
    match model {
        "denso-vs060" => vec![
            [-70.0, 65.0],
            [-20.0, 80.0],
            [45.0, 145.0],
            [-180.0, 180.0],
            [-110.0, 110.0],
            [-180.0, 180.0],
        ],
        _ => vec![
            [-60.0, 60.0],
            [-150.0, -30.0],
            [-150.0, 150.0],
            [-180.0, 180.0],
            [-120.0, 120.0],
            [-180.0, 180.0],
        ],
    }
}

fn deg(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x.to_degrees()).collect()
}

fn mat4(t: &Isometry3<f64>) -> Value {
    let m = t.to_homogeneous();
    Value::Array(
        (0..4)
            .map(|r| json!([m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]]))
            .collect(),
    )
}

fn quat_wxyz(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// The `robot` block of a header for a nominal chain (mm, deg).
pub fn robot_block(chain: &UrdfChain, serial: &str) -> Value {
    let joints: Vec<Value> = chain
        .joints
        .iter()
        .map(|j| {
            json!({
                "name": j.name,
                "origin_xyz": [j.origin_xyz_mm.x, j.origin_xyz_mm.y, j.origin_xyz_mm.z],
                "origin_rpy": deg(j.origin_rpy_rad.as_slice()),
                "axis": [j.axis.x, j.axis.y, j.axis.z],
                "limits": [j.limits_rad.0.to_degrees(), j.limits_rad.1.to_degrees()],
            })
        })
        .collect();
    json!({
        "model": chain.model,
        "serial": serial,
        "chain": joints,
        "flange": {
            "origin_xyz": [chain.flange_xyz_mm.x, chain.flange_xyz_mm.y, chain.flange_xyz_mm.z],
            "origin_rpy": deg(chain.flange_rpy_rad.as_slice()),
        },
    })
}

/// The effects of the world as the case-JSON list (`kind` + parameters with units).
pub fn effects_list(world: &WorldHandle, arm: usize, tracker: Option<usize>) -> Vec<Value> {
    let truth = world.truth();
    let mut v = Vec::new();
    if let Some(a) = truth.arms.get(arm) {
        let e = &a.physics.effects;
        for c in &e.joint_compliance {
            v.push(
                json!({"kind": "joint_compliance", "joint": c.joint, "rad_per_nm": c.rad_per_nm}),
            );
        }
        for c in &e.link_deflection {
            v.push(
                json!({"kind": "link_deflection", "joint": c.joint, "rad_per_nm": c.rad_per_nm}),
            );
        }
        for b in &e.backlash {
            v.push(
                json!({"kind": "backlash", "joint": b.joint, "lost_motion_deg": b.lost_motion_deg}),
            );
        }
        for x in &e.eccentricity {
            v.push(
                json!({"kind": "joint_eccentricity", "joint": x.joint, "sin1_deg": x.sin1_deg,
                "cos1_deg": x.cos1_deg, "sin2_deg": x.sin2_deg, "cos2_deg": x.cos2_deg}),
            );
        }
        for t in &e.transmission {
            v.push(json!({"kind": "transmission_ratio", "joint": t.joint, "ratio_error_ppm": t.ratio_error_ppm}));
        }
        if let Some(t) = &e.thermal {
            v.push(json!({"kind": "thermal_drift", "delta_t_inf_k": t.delta_t_inf_k, "tau_s": t.tau_s,
                "expansion_per_k": t.expansion_per_k, "offset_drift_deg_per_k": t.offset_drift_deg_per_k,
                "t_power_on_s": t.t_power_on_s}));
        }
        for r in &e.ripple {
            v.push(
                json!({"kind": "transmission_ripple", "joint": r.joint, "harmonic": r.harmonic,
                "amplitude_deg": r.amplitude_deg, "phase_deg": r.phase_deg}),
            );
        }
        for c in &e.coupling {
            v.push(json!({"kind": "joint_coupling", "joint": c.joint, "driver": c.driver,
                "harmonic": c.harmonic, "amplitude_deg": c.amplitude_deg, "phase_deg": c.phase_deg}));
        }
        for w in &e.wave_generator {
            v.push(json!({"kind": "wave_generator", "joint": w.joint, "gear_ratio": w.gear_ratio,
                "harmonic": w.harmonic, "amplitude_deg": w.amplitude_deg, "phase_deg": w.phase_deg}));
        }
        for c in &e.nonlinear_compliance {
            v.push(json!({"kind": "nonlinear_compliance", "joint": c.joint, "rad_per_nm2": c.rad_per_nm2}));
        }
        if e.servo_error_deg > 0.0 {
            v.push(json!({"kind": "servo_error", "servo_error_deg": e.servo_error_deg}));
        }
    }
    if let Some(t) = tracker.and_then(|i| truth.trackers.get(i)) {
        let e = &t.effects;
        if e.scale_ppm != 0.0 {
            v.push(json!({"kind": "tracker_scale", "scale_ppm": e.scale_ppm}));
        }
        if e.depth_scale_ppm != 0.0 {
            v.push(json!({"kind": "tracker_depth_scale", "depth_scale_ppm": e.depth_scale_ppm}));
        }
        if let Some(b) = &e.base_bump {
            v.push(json!({"kind": "base_shift", "t_s": b.t_s, "shift_mm": b.shift_mm, "rot_deg": b.rot_deg}));
        }
        if e.latency_s != 0.0 {
            v.push(json!({"kind": "latency", "latency_s": e.latency_s}));
        }
    }
    v
}

/// Average marker position and orientation over visible frames.
struct Averaged {
    p: Vector3<f64>,
    q: UnitQuaternion<f64>,
    rms: f64,
    frames: u32,
}

fn average_frames(world: &WorldHandle, tracker: usize, n: u32) -> Option<Averaged> {
    let mut sum = Vector3::zeros();
    let mut qsum = Vector4::zeros();
    let mut first: Option<UnitQuaternion<f64>> = None;
    let (mut rms, mut k) = (0.0, 0u32);
    for _ in 0..n {
        let f = world.tracker_frame_of(tracker);
        if let Some(ToolStatus::Visible { pose, rms_mm }) = f.tools.first().map(|t| t.status) {
            let iso = pose.0;
            sum += iso.translation.vector;
            let q = iso.rotation;
            let c = q.coords;
            let sign = match first {
                Some(f0) if f0.coords.dot(&c) < 0.0 => -1.0,
                Some(_) => 1.0,
                None => {
                    first = Some(q);
                    1.0
                }
            };
            qsum += c * sign;
            rms += rms_mm;
            k += 1;
        }
    }
    (k > 0).then(|| Averaged {
        p: sum / k as f64,
        q: UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(qsum / k as f64)),
        rms: rms / k as f64,
        frames: k,
    })
}

/// Noise-free check that the marker would be seen at `q` (moves nothing).
fn visible_at(world: &WorldHandle, arm: usize, tracker: usize, q: &[f64]) -> bool {
    let truth = world.truth();
    let (Some(a), Some(t)) = (truth.arms.get(arm), truth.trackers.get(tracker)) else {
        return false;
    };
    let ctx = crate::world::effects::JointContext::at_rest(q.len());
    let flange = a.physics.true_flange(q, &ctx);
    // Keep the flange above the table and away from the base column.
    let fp = flange.translation.vector;
    if fp.z < 100.0 || (fp.x * fp.x + fp.y * fp.y).sqrt() < 200.0 {
        return false;
    }
    let pose = t.tracker_in_base.inverse() * flange * t.marker_on_flange;
    let p = nalgebra::Point3::from(pose.translation.vector);
    if !crate::world::sensors::in_volume(t.volume, &p) {
        return false;
    }
    t.effects.max_view_angle_deg.is_none_or(|max| {
        let zm = pose.rotation * Vector3::z();
        zm.dot(&(-p.coords.normalize())).clamp(-1.0, 1.0).acos() <= max.to_radians()
    })
}

/// Synthesise a kinematic (tracker) acquisition from a virtual-clock world.
pub fn synthesize(world: &WorldHandle, cfg: &SynthConfig) -> Result<SynthOutput, SynthError> {
    if !world.is_virtual() {
        return Err(SynthError::NotVirtual);
    }
    let (arm, tracker) = (cfg.arm, cfg.tracker);
    let truth = world.truth();
    let at = truth.arms.get(arm).ok_or(SynthError::NoDevice("arm"))?;
    let tt = truth
        .trackers
        .get(tracker)
        .ok_or(SynthError::NoDevice("tracker"))?;
    let nominal = at.physics.nominal.clone();
    let (_, serial) = world.arm_identity(arm).unwrap_or_default();
    let region = cfg
        .region_deg
        .clone()
        .unwrap_or_else(|| default_region_deg(&nominal.model));
    let n_total = cfg.n_train + cfg.n_heldout;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);

    // Sample visible poses.
    let mut poses: Vec<Vec<f64>> = Vec::with_capacity(n_total);
    let max_tries = n_total * 200 + 1000;
    let mut tries = 0;
    while poses.len() < n_total && tries < max_tries {
        tries += 1;
        let q: Vec<f64> = nominal
            .joints
            .iter()
            .enumerate()
            .map(|(i, j)| {
                let r = region
                    .get(i)
                    .copied()
                    .unwrap_or([j.limits_rad.0.to_degrees(), j.limits_rad.1.to_degrees()]);
                let lo = r[0].max(j.limits_rad.0.to_degrees());
                let hi = r[1].min(j.limits_rad.1.to_degrees()).max(lo);
                rng.random_range(lo..=hi).to_radians()
            })
            .collect();
        if visible_at(world, arm, tracker, &q) {
            poses.push(q);
        }
    }
    if poses.len() < n_total {
        return Err(SynthError::NoPoses {
            found: poses.len(),
            wanted: n_total,
            tries,
        });
    }

    let tracker_kind = world
        .scenario()
        .trackers
        .get(tracker)
        .map(|t| t.kind.as_str().to_string())
        .unwrap_or_default();
    let header = json!({
        "format": "robocal-dataset/1",
        "created": cfg.created,
        "robot": robot_block(&nominal, &serial),
        "tracker": {"kind": tracker_kind},
        "plan": {"name": "synth-random", "kind": "random-joint-box"},
        "notes": format!("robocal-mocks synth seed {} (world seed {})", cfg.seed, world.scenario().seed),
    });
    let mut train = header.to_string() + "\n";
    let mut held = header.to_string() + "\n";
    let mut truth_csv = String::from("id,x_mm,y_mm,z_mm\n");
    let thermal = at.physics.effects.thermal.clone();
    let (mut n_tr, mut n_ho) = (0usize, 0usize);
    for (id, q_cmd) in poses.iter().enumerate() {
        let slot_start = world.now();
        let every = cfg.heldout_every.max(1);
        let validation = n_ho < cfg.n_heldout && (id % every == every - 1 || n_tr >= cfg.n_train);
        // Where the move into this pose starts (the record's `q_prev`).
        let q_from = world.arm_joint_state(arm).q;
        world.arm_start_move(arm, q_cmd, cfg.speed)?;
        let end = world.arm_motion_end(arm);
        let (js, approach, flange, marker_true, avg) =
            match cfg.in_motion {
                Some(f) => {
                    // The frame advances the clock by one frame period first: start one period
                    // early so that the frame and the joint state are of the same instant.
                    let period = world.tracker_info(tracker).map_or(0.0, |(_, r)| {
                        if r > 0.0 {
                            1.0 / r
                        } else {
                            0.0
                        }
                    });
                    let at = world.now() + f.clamp(0.0, 1.0) * (end - world.now()) - period;
                    if at > world.now() {
                        world.advance(at - world.now());
                    }
                    let avg = average_frames(world, tracker, 1);
                    let js = world.arm_joint_state(arm);
                    let approach = world.truth().arms[arm].approach.clone();
                    let flange = world.arm_controller_flange(arm);
                    let marker_true = world.marker_truth(tracker);
                    // Finish the move before the next one.
                    world.advance((end - world.now()).max(0.0));
                    (js, approach, flange, marker_true, avg)
                }
                None => {
                    world.advance(end - world.now());
                    let js = world.arm_joint_state(arm);
                    let approach = world.truth().arms[arm].approach.clone();
                    let flange = world.arm_controller_flange(arm);
                    let marker_true = world.marker_truth(tracker);
                    let avg = average_frames(world, tracker, cfg.frames_per_pose);
                    (js, approach, flange, marker_true, avg)
                }
            };
        let t = if cfg.in_motion.is_some() {
            js.t
        } else {
            world.now()
        };
        let mut rec = json!({
            "kind": "pose", "id": id, "t": t, "point": id, "branch": 0,
            "group": if validation { "validation" } else { "train" },
            "q_cmd": deg(q_cmd), "q": deg(&js.q), "q_prev": deg(&q_from),
            "flange": {"p": [flange.translation.x, flange.translation.y, flange.translation.z],
                       "quat": quat_wxyz(&flange.rotation)},
        });
        let marker = match &avg {
            Some(a) => json!({"p": [a.p.x, a.p.y, a.p.z], "quat": quat_wxyz(&a.q), "rms": a.rms,
                               "visible": true, "frames": a.frames}),
            None => json!({"visible": false, "frames": 0}),
        };
        rec["marker"] = marker;
        rec["approach"] = json!(approach);
        if let (Some(_), Some(qd)) = (cfg.in_motion, &js.qd) {
            rec["qd"] = json!(deg(qd));
        }
        if let Some(th) = &thermal {
            rec["temp_c"] = json!(22.0 + th.delta_t_k(t));
        }
        if validation {
            n_ho += 1;
            held += &(rec.to_string() + "\n");
            if let Some(m) = marker_true {
                let p = m.translation.vector;
                truth_csv += &format!("{id},{:.6},{:.6},{:.6}\n", p.x, p.y, p.z);
            }
        } else {
            n_tr += 1;
            train += &(rec.to_string() + "\n");
        }
        // Wait for the next slot (≈ pose_period_s with ±10 % jitter).
        let period = cfg.pose_period_s * (0.9 + 0.2 * rng.random::<f64>());
        let next = slot_start + period;
        if next > world.now() {
            world.advance(next - world.now());
        }
    }
    let truth = world.truth();
    let at = &truth.arms[arm];
    let case = json!({
        "seed": cfg.seed,
        "world_seed": world.scenario().seed,
        "model": nominal.model,
        "effects": effects_list(world, arm, Some(tracker)),
        "noise_mm_per_axis": tt.effects.noise_lateral_mm,
        "noise_depth_mm": tt.effects.noise_depth_mm,
        "frames_per_pose": cfg.frames_per_pose,
        "n_train": n_tr,
        "n_heldout": n_ho,
        "true_chain": at.physics.chain.joints.iter().map(|j| json!({
            "origin_xyz": [j.origin_xyz_mm.x, j.origin_xyz_mm.y, j.origin_xyz_mm.z],
            "origin_rpy_deg": deg(j.origin_rpy_rad.as_slice()),
            "axis": [j.axis.x, j.axis.y, j.axis.z],
        })).collect::<Vec<_>>(),
        "true_flange": {
            "origin_xyz": [at.physics.chain.flange_xyz_mm.x, at.physics.chain.flange_xyz_mm.y, at.physics.chain.flange_xyz_mm.z],
            "origin_rpy_deg": deg(at.physics.chain.flange_rpy_rad.as_slice()),
        },
        "joint_offsets_deg": deg(&at.physics.offsets_rad),
        "masses": at.physics.masses,
        "arm_effects": at.physics.effects,
        "tracker_effects": tt.effects,
        "marker_on_flange": mat4(&tt.marker_on_flange),
        "tracker_in_base": mat4(&tt.tracker_in_base),
    });
    let case_json = serde_json::to_string_pretty(&case).unwrap_or_default() + "\n";
    Ok(SynthOutput {
        train_jsonl: train,
        heldout_jsonl: held,
        truth_csv,
        case_json,
    })
}
