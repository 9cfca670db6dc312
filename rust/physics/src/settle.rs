//! Drop-and-settle with MuJoCo, keeping the compiled model and data between settles.

use std::collections::VecDeque;
use std::time::Instant;

use boxpose_data::Pose;
use mujoco_rs::mujoco_c::mjtWarning;
use mujoco_rs::prelude::*;

use crate::error::{PhysicsError, Result};
use crate::mjcf::{MujocoOptions, SUPPORT_PREFIX, box_name, to_mjcf_with};
use crate::scene::{SceneDescription, SettleParams, check_poses};

/// Distances beyond this are reported as this (m): the certificate is about contact, not about
/// how far apart distant boxes are.
pub const DISTANCE_HORIZON_M: f64 = 0.1;

/// Evidence that a scene is (or is not) at rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Certificate {
    /// Largest ‖v‖ of any box (its centre's linear velocity) over the stability window, m/s.
    pub max_linear_speed_mps: f64,
    /// Largest ‖ω‖ of any box over the stability window, rad/s.
    pub max_angular_speed_radps: f64,
    /// Smallest signed distance between any two bodies, support included, in the final state
    /// (MuJoCo's `mj_geomDistance`; negative = penetration; capped at [`DISTANCE_HORIZON_M`]).
    pub min_signed_distance_m: f64,
    /// Simulated time until the window closed (or `max_time_s` when not settled), s.
    pub settle_time_s: f64,
    /// Wall-clock time of the whole settle (reset, stepping, distance queries), s.
    pub wall_time_s: f64,
    /// Simulation steps taken.
    pub steps: usize,
}

/// Why a settled scene is not statically stable; the Drake stage's rejection reasons, checked
/// in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rejection {
    /// Some box moved faster than a threshold within the window ending at `max_time_s`.
    NotSettled,
    /// Two bodies (support included) interpenetrate by more than `max_penetration_m`.
    Penetration,
    /// A box centre is outside the support region or below its top surface.
    LeftSupport,
}

impl Rejection {
    /// The reason as the Drake stage words it (python/drake_scenes/settle.py).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NotSettled => "not settled in time",
            Self::Penetration => "penetration",
            Self::LeftSupport => "box left the support region",
        }
    }
}

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The result of one drop.
#[derive(Debug, Clone, PartialEq)]
pub struct SettleOutcome {
    /// Every box stayed under both speed thresholds over the whole window before `max_time_s`.
    pub settled: bool,
    /// Settled, no interpenetration deeper than `max_penetration_m`, every box on the support.
    pub stable: bool,
    /// Why not stable (`None` when stable).
    pub rejection: Option<Rejection>,
    /// Final `T_world_box` of every box (unit quaternion with w ≥ 0).
    pub poses: Vec<Pose>,
    pub certificate: Certificate,
}

/// A compiled scene, ready to settle from any initial poses of its boxes. Build it once per
/// scene layout (support, box sizes, masses, frictions) and call [`Settler::settle_from`] for
/// each sampled drop: the model is compiled once and the data buffers are reused.
pub struct Settler {
    data: MjData<Box<MjModel>>,
    scene: SceneDescription,
    params: SettleParams,
    options: MujocoOptions,
    mjcf: String,
    box_geoms: Vec<usize>,
    support_geoms: Vec<usize>,
}

impl std::fmt::Debug for Settler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Settler")
            .field("scene", &self.scene)
            .field("params", &self.params)
            .finish_non_exhaustive()
    }
}

/// Settles `scene` from its initial poses (compiles a fresh model; use [`Settler`] to settle
/// many drops of one scene).
pub fn settle(scene: &SceneDescription, params: &SettleParams) -> Result<SettleOutcome> {
    Settler::new(scene, params)?.settle()
}

/// Re-settles a pile after one box moved: every box of `pile` rests at its `settled` pose except
/// box `moved`, dropped from `drop`. The resting boxes start asleep and wake only when something
/// touches them (MuJoCo's sleeping islands), so the cost is that of the boxes the drop disturbs,
/// not of the whole pile. The certificate is measured on every awake box — the moved one never
/// sleeps — and a woken box sleeps again only below [`crate::RESETTLE_SLEEP_TOLERANCE`]; the
/// penetration and support checks cover every box. `drop` should be clear of the pile: boxes it
/// starts in contact with cannot start asleep (MuJoCo keeps their island awake and logs a warning).
pub fn resettle(
    pile: &SceneDescription,
    settled: &[Pose],
    moved: usize,
    drop: Pose,
    params: &SettleParams,
) -> Result<SettleOutcome> {
    let settled = check_poses(settled, pile.boxes.len())?;
    if moved >= pile.boxes.len() {
        return Err(PhysicsError::NoSuchBox {
            index: moved,
            count: pile.boxes.len(),
        });
    }
    let mut scene = pile.clone();
    for (i, (body, pose)) in scene.boxes.iter_mut().zip(settled).enumerate() {
        (body.initial, body.at_rest) = if i == moved {
            (drop, false)
        } else {
            (pose, true)
        };
    }
    Settler::new(&scene, params)?.settle()
}

impl Settler {
    /// Validates `scene` and `params` and compiles the scene's MJCF (default [`MujocoOptions`]).
    pub fn new(scene: &SceneDescription, params: &SettleParams) -> Result<Self> {
        Self::with_options(scene, params, &MujocoOptions::default())
    }

    /// As [`Settler::new`], with other MuJoCo settings (for tuning and benchmarks).
    pub fn with_options(
        scene: &SceneDescription,
        params: &SettleParams,
        options: &MujocoOptions,
    ) -> Result<Self> {
        scene.validate()?;
        params.validate()?;
        let mjcf = to_mjcf_with(scene, params, options);
        let model = MjModel::from_xml_string(&mjcf).map_err(|e| PhysicsError::Compile {
            message: compile_message(e),
        })?;
        let n = scene.boxes.len();
        let (nq, nv) = (model.ffi().nq as usize, model.ffi().nv as usize);
        if nq != 7 * n || nv != 6 * n {
            return Err(PhysicsError::MuJoCo(format!(
                "compiled model has nq = {nq}, nv = {nv}; expected {} and {} for {n} free boxes",
                7 * n,
                6 * n
            )));
        }
        let geom = |name: &str| {
            model
                .name_to_id(MjtObjBase::mjOBJ_GEOM, name)
                .ok_or_else(|| {
                    PhysicsError::MuJoCo(format!("geom `{name}` missing from the compiled model"))
                })
        };
        let box_geoms = (0..n)
            .map(|i| geom(&box_name(i)))
            .collect::<Result<Vec<_>>>()?;
        let mut support_geoms = Vec::new();
        for id in 0..model.ffi().ngeom as usize {
            if model
                .id_to_name(MjtObjBase::mjOBJ_GEOM, id)
                .is_some_and(|name| name.starts_with(SUPPORT_PREFIX))
            {
                support_geoms.push(id);
            }
        }
        let data = MjData::try_new(Box::new(model))
            .map_err(|e| PhysicsError::MuJoCo(format!("allocating mjData: {e:?}")))?;
        Ok(Self {
            data,
            scene: scene.clone(),
            params: *params,
            options: *options,
            mjcf,
            box_geoms,
            support_geoms,
        })
    }

    /// The MJCF the model was compiled from (the boxes at the scene's initial poses).
    pub fn mjcf(&self) -> &str {
        &self.mjcf
    }

    pub fn scene(&self) -> &SceneDescription {
        &self.scene
    }

    pub fn params(&self) -> &SettleParams {
        &self.params
    }

    /// Settles from the scene's own initial poses.
    pub fn settle(&mut self) -> Result<SettleOutcome> {
        let poses = self.scene.initial_poses();
        self.settle_from(&poses)
    }

    /// Drops the boxes from `initial` (one `T_world_box` per box, at rest) and steps until every
    /// box stays under the speed thresholds for the whole window, or `max_time_s` passes. Identical
    /// initial poses give identical outcomes (except wall time).
    pub fn settle_from(&mut self, initial: &[Pose]) -> Result<SettleOutcome> {
        let start = Instant::now();
        let initial = check_poses(initial, self.scene.boxes.len())?;
        let params = self.params;
        let options = self.options;
        let data = &mut self.data;
        data.reset();
        // a previous settle may have switched on the creep cure
        data.model_opt_mut().impratio = options.impratio;
        data.model_opt_mut().noslip_iterations = options.noslip_iterations as i32;
        let mut cure_at_step = options
            .creep_cure
            .map(|cure| (cure.after_s / params.time_step_s).round() as usize);
        {
            let qpos = data.qpos_mut();
            for (i, p) in initial.iter().enumerate() {
                qpos[7 * i..7 * i + 3].copy_from_slice(&p.translation);
                qpos[7 * i + 3..7 * i + 7].copy_from_slice(&p.quat_wxyz);
            }
        }
        data.forward();

        let (v_max, w_max) = (params.max_linear_speed_mps, params.max_angular_speed_radps);
        let window = params.window_steps();
        let max_steps = params.max_steps().max(window);
        let mut recent: VecDeque<(f64, f64)> = VecDeque::with_capacity(window + 1);
        let mut quiet = 0usize;
        let mut steps = 0usize;
        let mut settled = false;
        while steps < max_steps {
            if cure_at_step == Some(steps)
                && let Some(cure) = options.creep_cure
            {
                data.model_opt_mut().impratio = cure.impratio;
                data.model_opt_mut().noslip_iterations = cure.noslip_iterations as i32;
                cure_at_step = None;
            }
            data.step();
            steps += 1;
            check_warnings(data)?;
            let qvel = data.qvel();
            let (v, w) = max_speeds(qvel);
            if !qvel.iter().all(|x| x.is_finite()) {
                return Err(PhysicsError::Diverged {
                    time_s: data.time(),
                    warning: "non-finite velocity".into(),
                });
            }
            if recent.len() == window {
                recent.pop_front();
            }
            recent.push_back((v, w));
            quiet = if v <= v_max && w <= w_max {
                quiet + 1
            } else {
                0
            };
            if quiet >= window {
                settled = true;
                break;
            }
        }
        let (max_v, max_w) = recent
            .iter()
            .fold((0.0f64, 0.0f64), |(a, b), &(v, w)| (a.max(v), b.max(w)));
        let settle_time_s = data.time();

        let poses = final_poses(data.qpos());
        let min_signed_distance_m = self.min_signed_distance();
        let rejection = if !settled {
            Some(Rejection::NotSettled)
        } else if min_signed_distance_m < -params.max_penetration_m {
            Some(Rejection::Penetration)
        } else if !poses
            .iter()
            .all(|p| self.scene.support.holds(p.translation))
        {
            Some(Rejection::LeftSupport)
        } else {
            None
        };
        Ok(SettleOutcome {
            settled,
            stable: rejection.is_none(),
            rejection,
            poses,
            certificate: Certificate {
                max_linear_speed_mps: max_v,
                max_angular_speed_radps: max_w,
                min_signed_distance_m,
                settle_time_s,
                wall_time_s: start.elapsed().as_secs_f64(),
                steps,
            },
        })
    }

    /// Smallest signed distance over every box–box and box–support pair in the current state.
    fn min_signed_distance(&mut self) -> f64 {
        let mut min = DISTANCE_HORIZON_M;
        let boxes = &self.box_geoms;
        for (k, &a) in boxes.iter().enumerate() {
            for &b in boxes[k + 1..].iter().chain(&self.support_geoms) {
                min = min.min(self.data.geom_distance(a, b, DISTANCE_HORIZON_M, None));
            }
        }
        min
    }
}

fn compile_message(e: MjModelError) -> String {
    match e {
        MjModelError::LoadFailed(message) => message,
        other => format!("{other:?}"),
    }
}

/// Warnings after which the simulation cannot be trusted; MuJoCo resets the state on some of them.
const FATAL_WARNINGS: [(mjtWarning, &str); 5] = [
    (
        mjtWarning::mjWARN_BADQACC,
        "bad acceleration, MuJoCo reset the state",
    ),
    (mjtWarning::mjWARN_BADQPOS, "bad position"),
    (mjtWarning::mjWARN_BADQVEL, "bad velocity"),
    (mjtWarning::mjWARN_CONTACTFULL, "contact buffer full"),
    (mjtWarning::mjWARN_CNSTRFULL, "constraint buffer full"),
];

fn check_warnings(data: &MjData<Box<MjModel>>) -> Result<()> {
    let warnings = &data.ffi().warning;
    for (kind, what) in FATAL_WARNINGS {
        if warnings[kind as usize].number > 0 {
            return Err(PhysicsError::Diverged {
                time_s: data.time(),
                warning: what.to_string(),
            });
        }
    }
    Ok(())
}

/// Largest linear and angular speed over the free bodies (qvel of a free joint: linear velocity
/// in the world frame, then angular velocity in the body frame; norms do not depend on the frame).
fn max_speeds(qvel: &[f64]) -> (f64, f64) {
    qvel.chunks_exact(6).fold((0.0f64, 0.0f64), |(v, w), q| {
        let lin = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
        let ang = (q[3] * q[3] + q[4] * q[4] + q[5] * q[5]).sqrt();
        (v.max(lin), w.max(ang))
    })
}

fn final_poses(qpos: &[f64]) -> Vec<Pose> {
    qpos.chunks_exact(7)
        .map(|q| {
            let norm = (q[3] * q[3] + q[4] * q[4] + q[5] * q[5] + q[6] * q[6]).sqrt();
            let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
            Pose {
                quat_wxyz: [q[3], q[4], q[5], q[6]].map(|c| sign * c / norm),
                translation: [q[0], q[1], q[2]],
            }
        })
        .collect()
}
