//! The scene as MJCF: one description (the dataset rows and the recipe), rendered for MuJoCo.
//!
//! Contact model (chosen so boxes come to rest quickly and stay there; figures in
//! docs/benchmarks.md, tuning harness in examples/tune_settle.rs):
//! - `timestep` from the recipe, `integrator="implicitfast"`, Newton solver (MuJoCo's default)
//!   with `tolerance="1e-6"` (MuJoCo's 1e-8 costs ≈ 30 % more on 20-box piles, same verdicts),
//!   constraint islands solved separately (MuJoCo's default).
//! - `cone="elliptic"` with `impratio="10"`: elliptic friction cones are Coulomb's law (as
//!   Drake's), and a high impratio makes friction stiff, so resting boxes do not creep.
//!   Pyramidal cones are cheaper per step but leave piles creeping: 2 of 6 clutter scenes did
//!   not settle within 4 s.
//! - `condim="3"` (sliding friction only): a box resting on a face gets up to 4 (box–plane) or 8
//!   (box–box) contact points, which already resist spinning and rolling.
//! - `solref="0.01 1"`: contact time constant 10 ms (10 steps at 1 ms; MuJoCo's `refsafe` keeps it
//!   ≥ 2 steps) with critical damping: drops do not bounce, and resting penetration stays in the
//!   tens of micrometres (the recipes allow 2 mm). Stiffer (0.004) settles no better and costs
//!   more solver iterations; MuJoCo's 0.02 is as fast but lets boxes sink deeper.
//! - `solimp="0.95 0.99 0.001 0.5 2"`: impedance rising from 0.95 to 0.99 over 1 mm of
//!   penetration, so deeper penetration is pushed out harder.
//! - Friction as in Drake: every contact's coefficient is 2μ₁μ₂/(μ₁+μ₂) of the two surfaces'
//!   (boxes: their row's `friction`; support: [`SUPPORT_FRICTION`]). MuJoCo would take the larger
//!   of the two geoms' coefficients, so every pair that can touch is an explicit `<pair>` with
//!   the combined coefficient, and automatic collision detection is off (contype = 0); the
//!   pairs' bounding-sphere test is cheap next to the solver.
//! - No noslip iterations while a pile falls; a pile still moving after 0.75 s of simulated time gets
//!   impratio 100 and 10 noslip iterations, which stop the friction creep of soft contacts
//!   ([`CreepCure`]).
//! - No sleeping: sleeping trees report
//!   zero velocity, which would hollow out the certificate (`MujocoOptions::sleep_tolerance`
//!   turns it on for callers who only want poses). The exception is a re-settle
//!   ([`crate::resettle`]): the boxes of the settled pile start asleep (`sleep="init"`, each woken
//!   when touched, asleep again under [`RESETTLE_SLEEP_TOLERANCE`]), the moved box never sleeps.

use std::fmt::Write;

use crate::scene::{
    BIN_WALL_THICKNESS_M, GRAVITY_MPS2, PALLET_HEIGHT_M, SUPPORT_FRICTION, SceneDescription,
    SettleParams, SupportKind, combined_friction,
};

pub const CONTACT_SOLREF: [f64; 2] = [0.01, 1.0];
pub const CONTACT_SOLIMP: [f64; 5] = [0.95, 0.99, 0.001, 0.5, 2.0];
pub const IMPRATIO: f64 = 10.0;
/// MuJoCo's sleep velocity tolerance for the boxes of a pile being re-settled, once woken: a
/// fifth of the certificate's linear threshold (5 mm/s), so that only a box at rest sleeps again.
pub const RESETTLE_SLEEP_TOLERANCE: f64 = 1e-3;
/// Torsional and rolling coefficients (unused with condim 3, kept at MuJoCo's defaults).
const FRICTION_TAIL: &str = "0.005 0.0001";
/// The same for a `<pair>`, which has two rolling coefficients.
const PAIR_FRICTION_TAIL: &str = "0.005 0.0001 0.0001";

/// MuJoCo's constraint solvers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Solver {
    Newton,
    Cg,
    Pgs,
}

/// MuJoCo's integrators (the ones that make sense for free boxes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Integrator {
    Euler,
    ImplicitFast,
}

/// MuJoCo's friction cone models.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cone {
    Elliptic,
    Pyramidal,
}

/// The MuJoCo settings of the generated model; [`MujocoOptions::default`] is the documented
/// choice (module docs), the other values exist for tuning and benchmarks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MujocoOptions {
    pub integrator: Integrator,
    pub solver: Solver,
    pub cone: Cone,
    pub impratio: f64,
    pub solref: [f64; 2],
    pub solimp: [f64; 5],
    /// Solver tolerance and iteration caps (MuJoCo's `tolerance`, `iterations`, `ls_iterations`).
    pub tolerance: f64,
    pub iterations: u32,
    pub ls_iterations: u32,
    pub noslip_iterations: u32,
    /// Solve independent constraint islands separately (MuJoCo's `island` flag).
    pub islands: bool,
    /// Let trees at rest sleep (MuJoCo's `sleep` flag) below this `sleep_tolerance`; `None`: never.
    pub sleep_tolerance: Option<f64>,
    /// Dense constraint Jacobian and Hessian (MuJoCo picks sparse from 60 degrees of freedom,
    /// i.e. 10 boxes, on its own).
    pub dense: bool,
    /// Explicit `<pair>`s with Drake's friction combination (true), or MuJoCo's automatic
    /// collision detection with its own rule, the larger of the two coefficients (false).
    pub drake_friction: bool,
    /// Stiffer friction for a pile still moving after this much simulated time; `None`: never.
    pub creep_cure: Option<CreepCure>,
}

/// Soft contacts let a box leaning in a pile creep down at about a millimetre per second, so a
/// few Drake-certified piles never stay under the certificate's thresholds for a whole window.
/// A pile not yet at rest after `after_s` of simulated time gets these solver settings for the
/// rest of its settle (MuJoCo reads them at every step): friction made stiff by the impedance
/// ratio and enforced by noslip iterations, which remove the creep. The certificate is still the
/// boxes' own speeds; piles that settle before `after_s` never see the switch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CreepCure {
    pub after_s: f64,
    pub impratio: f64,
    pub noslip_iterations: u32,
}

/// The default cure: after 0.75 s of simulated time (a 5-box drop is usually at rest by then),
/// impratio 100 and 10 noslip iterations. Used from the start these certify every Drake-certified
/// pile of the benchmark set at 1.6–2× the cost per step; switched on at 0.75 s they still do, at
/// 12–32 % more time per settle on an idle machine; at 1 s one pile of 17 is missed
/// (docs/benchmarks.md).
pub const CREEP_CURE: CreepCure = CreepCure {
    after_s: 0.75,
    impratio: 100.0,
    noslip_iterations: 10,
};

impl Default for MujocoOptions {
    fn default() -> Self {
        Self {
            integrator: Integrator::ImplicitFast,
            solver: Solver::Newton,
            cone: Cone::Elliptic,
            impratio: IMPRATIO,
            solref: CONTACT_SOLREF,
            solimp: CONTACT_SOLIMP,
            tolerance: 1e-6,
            iterations: 100,
            ls_iterations: 50,
            noslip_iterations: 0,
            islands: true,
            dense: false,
            sleep_tolerance: None,
            drake_friction: true,
            creep_cure: Some(CREEP_CURE),
        }
    }
}

/// Name of box `i`'s body, joint and geom.
pub fn box_name(i: usize) -> String {
    format!("box_{i}")
}

/// Name prefix of the support's geoms.
pub const SUPPORT_PREFIX: &str = "support";

fn v(values: &[f64]) -> String {
    values
        .iter()
        .map(|x| format!("{x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The MJCF text of `scene`, boxes placed at their initial poses, with the default options.
pub fn to_mjcf(scene: &SceneDescription, params: &SettleParams) -> String {
    to_mjcf_with(scene, params, &MujocoOptions::default())
}

/// The MJCF text of `scene` with explicit MuJoCo options.
pub fn to_mjcf_with(scene: &SceneDescription, params: &SettleParams, o: &MujocoOptions) -> String {
    let mut s = String::new();
    let [hx, hy] = scene.support.half_extent_m;
    let solver = match o.solver {
        Solver::Newton => "Newton",
        Solver::Cg => "CG",
        Solver::Pgs => "PGS",
    };
    let integrator = match o.integrator {
        Integrator::Euler => "Euler",
        Integrator::ImplicitFast => "implicitfast",
    };
    let cone = match o.cone {
        Cone::Elliptic => "elliptic",
        Cone::Pyramidal => "pyramidal",
    };
    // Automatic collision detection only when the pairs are not listed explicitly.
    let contype = u8::from(!o.drake_friction);
    // A pile being re-settled: its boxes at rest start asleep, the others never sleep (their
    // speeds are the certificate).
    let resting = scene.boxes.iter().any(|b| b.at_rest);
    let sleep_tolerance = o
        .sleep_tolerance
        .or(resting.then_some(RESETTLE_SLEEP_TOLERANCE));
    // `writeln!` into a String cannot fail.
    let _ = writeln!(s, r#"<mujoco model="boxpose">"#);
    let _ = writeln!(s, r#"  <compiler angle="radian" autolimits="true"/>"#);
    let _ = writeln!(
        s,
        r#"  <option timestep="{}" gravity="0 0 {}" integrator="{integrator}" solver="{solver}" cone="{cone}" impratio="{}" tolerance="{}" iterations="{}" ls_iterations="{}" noslip_iterations="{}" jacobian="{}"{}>"#,
        params.time_step_s,
        -GRAVITY_MPS2,
        o.impratio,
        o.tolerance,
        o.iterations,
        o.ls_iterations,
        o.noslip_iterations,
        if o.dense { "dense" } else { "auto" },
        sleep_tolerance
            .map(|t| format!(r#" sleep_tolerance="{t}""#))
            .unwrap_or_default()
    );
    let _ = writeln!(
        s,
        r#"    <flag island="{}" sleep="{}"/>"#,
        if o.islands { "enable" } else { "disable" },
        if sleep_tolerance.is_some() {
            "enable"
        } else {
            "disable"
        }
    );
    let _ = writeln!(s, "  </option>");
    let _ = writeln!(s, r#"  <size memory="{}M"/>"#, 4 + scene.boxes.len() / 4);
    let _ = writeln!(s, "  <default>");
    let _ = writeln!(
        s,
        r#"    <geom contype="{contype}" conaffinity="{contype}" condim="3" solref="{}" solimp="{}" margin="0" friction="{SUPPORT_FRICTION} {FRICTION_TAIL}"/>"#,
        v(&o.solref),
        v(&o.solimp)
    );
    let _ = writeln!(
        s,
        r#"    <pair condim="3" solref="{}" solimp="{}" margin="0"/>"#,
        v(&o.solref),
        v(&o.solimp)
    );
    let _ = writeln!(s, "  </default>");
    let _ = writeln!(s, "  <worldbody>");
    let ground = format!("{SUPPORT_PREFIX}_ground");
    let reach = 4.0 * hx.max(hy);
    let _ = writeln!(
        s,
        r#"    <geom name="{ground}" type="plane" size="{reach} {reach} 0.05"/>"#
    );
    let mut support = vec![ground];
    let mut slab = |s: &mut String, name: &str, pos: [f64; 3], half: [f64; 3]| {
        let name = format!("{SUPPORT_PREFIX}_{name}");
        let _ = writeln!(
            s,
            r#"    <geom name="{name}" type="box" pos="{}" size="{}"/>"#,
            v(&pos),
            v(&half)
        );
        support.push(name);
    };
    match scene.support.kind {
        SupportKind::Floor => {}
        SupportKind::Bin => {
            let (t, h) = (
                BIN_WALL_THICKNESS_M / 2.0,
                scene.support.wall_height_m / 2.0,
            );
            slab(&mut s, "wall_px", [hx + t, 0.0, h], [t, hy + 2.0 * t, h]);
            slab(&mut s, "wall_nx", [-hx - t, 0.0, h], [t, hy + 2.0 * t, h]);
            slab(&mut s, "wall_py", [0.0, hy + t, h], [hx, t, h]);
            slab(&mut s, "wall_ny", [0.0, -hy - t, h], [hx, t, h]);
        }
        SupportKind::Pallet => slab(
            &mut s,
            "deck",
            [0.0, 0.0, PALLET_HEIGHT_M / 2.0],
            [hx, hy, PALLET_HEIGHT_M / 2.0],
        ),
    }
    for (i, b) in scene.boxes.iter().enumerate() {
        let name = box_name(i);
        let sleep = match (resting, b.at_rest) {
            (false, _) => "",
            (true, true) => r#" sleep="init""#,
            (true, false) => r#" sleep="never""#,
        };
        let _ = writeln!(
            s,
            r#"    <body name="{name}" pos="{}" quat="{}"{sleep}>"#,
            v(&b.initial.translation),
            v(&b.initial.quat_wxyz)
        );
        let _ = writeln!(s, r#"      <freejoint name="{name}"/>"#);
        let _ = writeln!(
            s,
            r#"      <inertial pos="0 0 0" mass="{}" diaginertia="{}"/>"#,
            b.mass_kg,
            v(&b.diag_inertia())
        );
        let _ = writeln!(
            s,
            r#"      <geom name="{name}" type="box" size="{}" friction="{} {FRICTION_TAIL}"/>"#,
            v(&b.size.map(|x| x / 2.0)),
            b.friction
        );
        let _ = writeln!(s, "    </body>");
    }
    let _ = writeln!(s, "  </worldbody>");
    if o.drake_friction {
        let _ = writeln!(s, "  <contact>");
        let pair = |s: &mut String, a: &str, b: &str, mu: f64| {
            let _ = writeln!(
                s,
                r#"    <pair geom1="{a}" geom2="{b}" friction="{mu} {mu} {PAIR_FRICTION_TAIL}"/>"#
            );
        };
        for (i, bi) in scene.boxes.iter().enumerate() {
            for g in &support {
                pair(
                    &mut s,
                    &box_name(i),
                    g,
                    combined_friction(bi.friction, SUPPORT_FRICTION),
                );
            }
            for (j, bj) in scene.boxes.iter().enumerate().skip(i + 1) {
                pair(
                    &mut s,
                    &box_name(i),
                    &box_name(j),
                    combined_friction(bi.friction, bj.friction),
                );
            }
        }
        let _ = writeln!(s, "  </contact>");
    }
    let _ = writeln!(s, "</mujoco>");
    s
}
