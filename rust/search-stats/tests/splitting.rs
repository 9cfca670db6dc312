//! Subset simulation validated on analytic failure functions over a z-space shaped like
//! `single_box`'s: 14 scalar parameters z[0..14] and the target's orientation block z[14..18].
//! Each failure probability is known in closed form; failure ⇔ score > 0.
//!
//! The quick tests run in `make test`. The 1000-repetition study behind `#[ignore]` gives the
//! figures of docs/search.md ("Subset simulation"):
//!
//! `cargo test --release -p boxpose-search-stats --test splitting -- --ignored --nocapture`

mod common;

use boxpose_search_stats::splitting::{SplittingConfig, SplittingRun, run_in_memory};
use boxpose_search_stats::{normal_cdf, normal_quantile};
use common::analytic::{binomial_acceptance, monte_carlo_evaluations, rotation_angle_for};

/// Dimension of `single_box`'s z: 14 scalars and one orientation block.
const DIM: usize = 18;
/// Where the orientation block starts (as in `single_box`, after the scalars).
const BLOCK: usize = 14;
/// Seeded repetitions per quick coverage test.
const REPS: u64 = 100;

/// A unit vector over the 14 scalar dimensions (not axis-aligned, so every coordinate moves).
fn direction(weights: [f64; BLOCK]) -> [f64; BLOCK] {
    let norm = weights.iter().map(|w| w * w).sum::<f64>().sqrt();
    weights.map(|w| w / norm)
}

fn project(a: &[f64; BLOCK], z: &[f64]) -> f64 {
    a.iter().zip(z).map(|(a, x)| a * x).sum()
}

/// An analytic failure set with its exact probability.
enum Problem {
    /// aᵀz > β, p = 1 − Φ(β).
    Linear { a: [f64; BLOCK], beta: f64 },
    /// Three modes of unequal mass: aᵀz > β₁ and aᵀz < −β₂ (disjoint, opposite sides of the
    /// origin) and cᵀz > β₃ with c ⊥ a (independent of the first two). The score is the largest
    /// margin, so every level set is a union of three half-spaces.
    /// p = 1 − (1 − p₁ − p₂)(1 − p₃).
    MultiMode {
        a: [f64; BLOCK],
        c: [f64; BLOCK],
        betas: [f64; 3],
    },
    /// The orientation within ω₀ of a fixed q₀ (q ≡ −q, mass F(ω₀) = (ω₀ − sin ω₀)/π) and
    /// z[0] > β: p = F(ω₀)(1 − Φ(β)). Exercises the rotation move.
    RotationCap {
        q0: [f64; 4],
        cos_half: f64,
        beta: f64,
    },
    /// (aᵀz + c·n)/√(1 + c²) > β, with n = Φ⁻¹(u) read from the scene seed (u its uniform
    /// quantile): a failure that depends on what the search draws from the seed (appearance,
    /// render noise) as much as on z when c = 1. p = 1 − Φ(β).
    Nuisance { a: [f64; BLOCK], c: f64, beta: f64 },
}

/// The standard normal a scene seed stands for (seeds are uniform on [0, 2⁶³)).
fn seed_normal(scene_seed: u64) -> f64 {
    normal_quantile((scene_seed as f64 + 0.5) / 2f64.powi(63))
}

/// Mass of the rotation cap of [`Problem::rotation_cap`].
const CAP_MASS: f64 = 0.02;

impl Problem {
    fn linear(p: f64) -> Self {
        Problem::Linear {
            a: direction([
                1.0, -0.5, 0.3, 0.8, -0.2, 0.6, 0.1, -0.7, 0.4, 0.2, -0.3, 0.5, 0.9, -0.1,
            ]),
            beta: normal_quantile(1.0 - p),
        }
    }

    /// Modes of mass `masses` (unequal; their union has the probability [`Self::p`]).
    fn multi_mode(masses: [f64; 3]) -> Self {
        let a = direction([
            1.0, 0.5, -0.5, 0.0, 0.3, 0.0, 0.2, 0.0, -0.4, 0.0, 0.1, 0.0, 0.6, 0.0,
        ]);
        // c ⊥ a: c lives where a is zero, plus a component cancelled against a.
        let mut c = [
            0.0, 0.0, 0.0, 1.0, 0.0, -0.8, 0.0, 0.5, 0.0, 0.7, 0.0, -0.3, 0.0, 0.4,
        ];
        let overlap = project(&a, &c);
        for (cj, aj) in c.iter_mut().zip(&a) {
            *cj -= overlap * aj;
        }
        Problem::MultiMode {
            a,
            c: direction(c),
            betas: masses.map(|m| normal_quantile(1.0 - m)),
        }
    }

    fn rotation_cap(p: f64) -> Self {
        let q0 = [0.5f64, -0.3, 0.7, 0.4];
        let n = q0.iter().map(|x| x * x).sum::<f64>().sqrt();
        Problem::RotationCap {
            q0: q0.map(|x| x / n),
            cos_half: (0.5 * rotation_angle_for(CAP_MASS)).cos(),
            beta: normal_quantile(1.0 - p / CAP_MASS),
        }
    }

    /// `c`: the nuisance's weight against z's (1: half the variance of the failure's margin).
    fn nuisance(p: f64, c: f64) -> Self {
        let Problem::Linear { a, beta } = Problem::linear(p) else {
            unreachable!()
        };
        Problem::Nuisance { a, c, beta }
    }

    /// The exact failure probability.
    fn p(&self) -> f64 {
        let tail = |b: f64| 1.0 - normal_cdf(b);
        match self {
            Problem::Linear { beta, .. } => tail(*beta),
            Problem::MultiMode { betas, .. } => {
                1.0 - (1.0 - tail(betas[0]) - tail(betas[1])) * (1.0 - tail(betas[2]))
            }
            Problem::RotationCap { beta, .. } => CAP_MASS * tail(*beta),
            Problem::Nuisance { beta, .. } => tail(*beta),
        }
    }

    /// The margin of each mode (a failure is in every mode whose margin is > 0).
    fn margins(&self, z: &[f64], scene_seed: u64) -> Vec<f64> {
        match self {
            Problem::Linear { a, beta } => vec![project(a, z) - beta],
            Problem::MultiMode { a, c, betas } => {
                let x = project(a, z);
                vec![x - betas[0], -x - betas[1], project(c, z) - betas[2]]
            }
            Problem::RotationCap { q0, cos_half, beta } => {
                let block = &z[BLOCK..BLOCK + 4];
                let r = block.iter().map(|x| x * x).sum::<f64>().sqrt();
                let dot = q0.iter().zip(block).map(|(a, b)| a * b).sum::<f64>() / r;
                vec![(5.0 * (dot.abs() - cos_half)).min(z[0] - beta)]
            }
            Problem::Nuisance { a, c, beta } => {
                vec![(project(a, z) + c * seed_normal(scene_seed)) / (1.0 + c * c).sqrt() - beta]
            }
        }
    }

    fn score(&self, z: &[f64], scene_seed: u64) -> f64 {
        self.margins(z, scene_seed)
            .into_iter()
            .fold(f64::NEG_INFINITY, f64::max)
    }

    fn name(&self) -> String {
        match self {
            Problem::Linear { .. } => format!("linear, p = {:.0e}", self.p()),
            Problem::MultiMode { .. } => format!("three modes, p = {:.2e}", self.p()),
            Problem::RotationCap { .. } => format!("rotation cap ∧ z₀, p = {:.0e}", self.p()),
            Problem::Nuisance { c, .. } => {
                format!(
                    "linear in z and the scene seed (c = {c}), p = {:.0e}",
                    self.p()
                )
            }
        }
    }

    fn run(&self, config: &SplittingConfig, seed: u64) -> SplittingRun {
        run_in_memory(config, DIM, &[BLOCK], seed, |z, scene_seed| {
            self.score(z, scene_seed)
        })
        .expect("splitting run")
    }
}

/// What repeated runs of one problem measured.
struct Study {
    reps: u64,
    /// Runs whose log-normal 95 % interval covered the truth.
    covered: u64,
    /// The same for the normal interval p̂(1 ± 1.96 δ).
    covered_normal: u64,
    /// The same for the log-normal interval from Au & Beck's δ alone.
    covered_au_beck: u64,
    /// Runs whose interval lay wholly below / above the truth.
    missed_low: u64,
    missed_high: u64,
    mean_evaluations: f64,
    /// √(mean ((p̂ − p)/p)²) over the runs.
    relative_rmse: f64,
    /// Median reported δ.
    median_delta: f64,
    /// Runs whose final failures lie in every mode.
    every_mode: u64,
    /// Mean share of the final failures per mode, and of their distinct ancestors.
    mode_share: Vec<f64>,
    mean_distinct_ancestors: f64,
    mean_acceptance: f64,
    mean_levels: f64,
}

impl Study {
    /// Evaluations for a 10 % relative error: δ² ∝ 1/N at a fixed number of levels, so
    /// mean evaluations × (relative RMSE / 0.1)².
    fn evaluations_for_10pct(&self) -> f64 {
        self.mean_evaluations * (self.relative_rmse / 0.1).powi(2)
    }

    /// The same from the median reported δ.
    fn evaluations_for_10pct_reported(&self) -> f64 {
        self.mean_evaluations * (self.median_delta / 0.1).powi(2)
    }
}

fn study(problem: &Problem, config: &SplittingConfig, reps: u64, seed0: u64) -> Study {
    let truth = problem.p();
    let modes = problem.margins(&[0.0; DIM], 0).len();
    let z975 = normal_quantile(0.975);
    let mut s = Study {
        reps,
        covered: 0,
        covered_normal: 0,
        covered_au_beck: 0,
        missed_low: 0,
        missed_high: 0,
        mean_evaluations: 0.0,
        relative_rmse: 0.0,
        median_delta: 0.0,
        every_mode: 0,
        mode_share: vec![0.0; modes],
        mean_distinct_ancestors: 0.0,
        mean_acceptance: 0.0,
        mean_levels: 0.0,
    };
    let mut deltas = Vec::new();
    let mut acceptances = 0usize;
    for r in 0..reps {
        let run = problem.run(config, seed0 + r);
        assert!(
            run.reached,
            "{}: seed {} did not reach",
            problem.name(),
            seed0 + r
        );
        let e = run
            .estimate
            .as_ref()
            .expect("reached runs have an estimate");
        let (lo, hi) = e.ci95;
        s.covered += (lo <= truth && truth <= hi) as u64;
        s.missed_low += (hi < truth) as u64;
        s.missed_high += (lo > truth) as u64;
        let half = z975 * e.coefficient_of_variation * e.p_hat;
        s.covered_normal += ((e.p_hat - truth).abs() <= half) as u64;
        let sigma_log = e.au_beck_coefficient_of_variation.powi(2).ln_1p().sqrt();
        s.covered_au_beck += ((truth / e.p_hat).ln().abs() <= z975 * sigma_log) as u64;
        s.mean_evaluations += run.evaluations as f64;
        s.relative_rmse += ((e.p_hat - truth) / truth).powi(2);
        deltas.push(e.coefficient_of_variation);
        let mut in_mode = vec![0usize; modes];
        for f in &run.failures {
            let margins = problem.margins(&f.z, f.scene_seed);
            let mode = (0..modes)
                .max_by(|&i, &j| margins[i].total_cmp(&margins[j]))
                .expect("at least one mode");
            in_mode[mode] += 1;
        }
        s.every_mode += in_mode.iter().all(|&k| k > 0) as u64;
        for (share, k) in s.mode_share.iter_mut().zip(&in_mode) {
            *share += *k as f64 / run.failures.len() as f64;
        }
        s.mean_distinct_ancestors += run.distinct_ancestors as f64;
        s.mean_levels += run.levels.len() as f64;
        for level in &run.levels {
            if let Some(a) = level.acceptance_rate {
                s.mean_acceptance += a;
                acceptances += 1;
            }
        }
    }
    let n = reps as f64;
    s.mean_evaluations /= n;
    s.relative_rmse = (s.relative_rmse / n).sqrt();
    deltas.sort_by(f64::total_cmp);
    s.median_delta = deltas[deltas.len() / 2];
    s.mode_share.iter_mut().for_each(|x| *x /= n);
    s.mean_distinct_ancestors /= n;
    s.mean_levels /= n;
    s.mean_acceptance /= acceptances.max(1) as f64;
    s
}

fn print_study(problem: &Problem, config: &SplittingConfig, s: &Study) {
    let (lo, hi) = binomial_acceptance(s.reps, 0.95, 0.01);
    let mc = monte_carlo_evaluations(problem.p());
    println!(
        "{}, N = {}: covered {}/{} log-normal (missed low {}, high {}), {}/{} normal, {}/{} from δ_AB alone, \
         acceptance region \
         [{lo}, {hi}]; {:.1} stages, {:.0} evaluations, relative RMSE {:.3}, median δ {:.3}; \
         10 % RE: {:.0} evaluations ({:.0} from δ), MC {mc:.3e}: {:.0}× ({:.0}×); every mode in \
         {}/{} runs, mode shares {:?}, {:.1} distinct ancestors, acceptance {:.2}",
        problem.name(),
        config.particles,
        s.covered,
        s.reps,
        s.missed_low,
        s.missed_high,
        s.covered_normal,
        s.reps,
        s.covered_au_beck,
        s.reps,
        s.mean_levels,
        s.mean_evaluations,
        s.relative_rmse,
        s.median_delta,
        s.evaluations_for_10pct(),
        s.evaluations_for_10pct_reported(),
        mc / s.evaluations_for_10pct(),
        mc / s.evaluations_for_10pct_reported(),
        s.every_mode,
        s.reps,
        s.mode_share
            .iter()
            .map(|x| (x * 1000.0).round() / 1000.0)
            .collect::<Vec<_>>(),
        s.mean_distinct_ancestors,
        s.mean_acceptance,
    );
}

fn assert_covers(problem: &Problem, s: &Study) {
    let (lo, hi) = binomial_acceptance(s.reps, 0.95, 0.01);
    assert!(
        (lo..=hi).contains(&s.covered),
        "{}: coverage {}/{} outside the 1 % binomial acceptance region [{lo}, {hi}] of 95 %",
        problem.name(),
        s.covered,
        s.reps
    );
}

#[test]
fn exact_probabilities() {
    // The multi-mode set's total against its parts (the modes on opposite sides are disjoint,
    // the third independent of them), and c ⊥ a.
    let problem = Problem::multi_mode(MODE_MASSES);
    let Problem::MultiMode { a, c, .. } = &problem else {
        unreachable!()
    };
    assert!(project(a, c).abs() < 1e-12);
    assert!((problem.p() / 1e-6 - 1.0).abs() < 1e-6);
    assert!((Problem::linear(1e-4).p() / 1e-4 - 1.0).abs() < 1e-9);
    assert!((Problem::rotation_cap(1e-4).p() / 1e-4 - 1.0).abs() < 1e-9);
    assert_eq!(binomial_acceptance(100, 0.95, 0.01), (89, 100));
}

/// Particles for the quick coverage tests at p = 1e-6: the 1000-run study (docs/search.md)
/// measures the interval's coverage there at 93.1 % with 2000 particles (the edge of the
/// acceptance region [931, 967]) and 94.5 % with 4000.
const PARTICLES_AT_1E6: usize = 4000;

fn with_particles(particles: usize) -> SplittingConfig {
    SplittingConfig {
        particles,
        ..SplittingConfig::default()
    }
}

#[test]
fn coverage_linear() {
    for (i, (p, particles)) in [(1e-3, 2000), (1e-4, 2000), (1e-6, PARTICLES_AT_1E6)]
        .into_iter()
        .enumerate()
    {
        let problem = Problem::linear(p);
        let config = with_particles(particles);
        let s = study(&problem, &config, REPS, 10_000 * (i as u64 + 1));
        print_study(&problem, &config, &s);
        assert_covers(&problem, &s);
    }
}

#[test]
fn coverage_rotation_cap() {
    let problem = Problem::rotation_cap(1e-4);
    let config = SplittingConfig::default();
    let s = study(&problem, &config, REPS, 40_000);
    print_study(&problem, &config, &s);
    assert_covers(&problem, &s);
}

#[test]
fn splitting_beats_monte_carlo_hundredfold_at_1e6() {
    // The target: ≥ 100× fewer evaluations than Monte Carlo for 10 % relative error
    // at p = 1e-6, from the measured error and from the reported δ alike.
    let config = SplittingConfig::default();
    for (problem, seed0) in [
        (Problem::linear(1e-6), 50_000),
        (Problem::multi_mode(MODE_MASSES), 60_000),
    ] {
        let s = study(&problem, &config, REPS, seed0);
        print_study(&problem, &config, &s);
        let mc = monte_carlo_evaluations(problem.p());
        assert!(
            mc / s.evaluations_for_10pct() >= 100.0,
            "{}: only {:.0}×",
            problem.name(),
            mc / s.evaluations_for_10pct()
        );
        assert!(mc / s.evaluations_for_10pct_reported() >= 100.0);
    }
}

/// The multi-mode set's masses: unequal, 1e-6 in all.
const MODE_MASSES: [f64; 3] = [6e-7, 3e-7, 1e-7];

#[test]
fn multi_mode_coverage_and_modes_found() {
    let problem = Problem::multi_mode(MODE_MASSES);
    let config = with_particles(PARTICLES_AT_1E6);
    let s = study(&problem, &config, REPS, 70_000);
    print_study(&problem, &config, &s);
    assert_covers(&problem, &s);
    // Splitting does lose a mode now and then: chains never cross between the half-spaces,
    // so a mode lives on through its own few lineages, and a level whose N·p₀ best particles
    // all lie in the other modes ends it. Measured: the 10 % mode is missing from the final
    // failures of 6.3 % of runs at 2000 particles and 0.4 % at 4000 (1000-run study,
    // docs/search.md); the test holds the rate at 4000 particles to at most 5 %. Such a run's p̂ lacks that mode's mass;
    // nothing in the run itself shows it (a second independent run may disagree).
    assert!(
        s.every_mode * 100 >= 95 * s.reps,
        "final failures miss a mode in {} of {} runs",
        s.reps - s.every_mode,
        s.reps
    );
    // The final failures are shared among the modes like the modes' masses (0.6, 0.3, 0.1):
    // no mode is starved on average.
    for (share, mass) in s.mode_share.iter().zip([0.6, 0.3, 0.1]) {
        assert!(
            (share - mass).abs() < 0.05,
            "mode shares {:?} vs masses (0.6, 0.3, 0.1)",
            s.mode_share
        );
    }
}

/// Keeping a chain's scene seed pays where failure depends on it: at p = 1e-6 with a fifth of
/// the margin's variance from the seed, drawing a new seed at every move (0, the only kernel
/// before 2026-12-07) needed 3.1× the evaluations of the default for a 10 % relative error, and
/// its interval covered at the edge of the acceptance region (88/100).
#[test]
fn keeping_the_scene_seed_pays_where_failure_depends_on_it() {
    let problem = Problem::nuisance(1e-6, 0.5);
    let kept = with_particles(2000);
    let fresh = SplittingConfig {
        keep_scene_seed: 0.0,
        ..kept.clone()
    };
    let s_kept = study(&problem, &kept, REPS, 90_000);
    let s_fresh = study(&problem, &fresh, REPS, 90_000);
    print_study(&problem, &kept, &s_kept);
    print_study(&problem, &fresh, &s_fresh);
    assert_covers(&problem, &s_kept);
    assert!(
        2.0 * s_kept.evaluations_for_10pct() < s_fresh.evaluations_for_10pct(),
        "keeping the seed: {:.0} evaluations for 10 % against {:.0} drawing it afresh",
        s_kept.evaluations_for_10pct(),
        s_fresh.evaluations_for_10pct()
    );
    assert!(s_kept.mean_distinct_ancestors > s_fresh.mean_distinct_ancestors);
}

/// Keeping a chain's scene seed, where failure depends on it as much as on z: how many
/// evaluations each probability of keeping it needs (docs/search.md, "Subset simulation").
#[test]
#[ignore = "a study (a minute in release): cargo test --release -p boxpose-search-stats --test splitting keep_scene_seed_study -- --ignored --nocapture"]
fn keep_scene_seed_study() {
    // (c = 1, p = 1e-6 drawing the seed afresh is left out: a stage's chains never move, and
    // the run stops with the plateau error)
    for (p, c, keeps) in [
        (1e-4, 0.5, &[0.0, 0.8, 0.9][..]),
        (1e-6, 0.5, &[0.0, 0.8, 0.9]),
        (1e-4, 1.0, &[0.0, 0.5, 0.8, 0.9]),
        (1e-6, 1.0, &[0.5, 0.8, 0.9]),
    ] {
        let problem = Problem::nuisance(p, c);
        for &keep in keeps {
            let config = SplittingConfig {
                keep_scene_seed: keep,
                ..with_particles(2000)
            };
            let s = study(&problem, &config, REPS, 90_000);
            print!("keep the scene seed {keep}: ");
            print_study(&problem, &config, &s);
        }
    }
}

/// The heavier study of docs/search.md: 1000 seeded runs per row.
#[test]
#[ignore = "a 1000-run study (minutes in release): cargo test --release -p boxpose-search-stats --test splitting -- --ignored --nocapture"]
fn study_1000_repetitions() {
    let rows = [
        (Problem::linear(1e-3), 2000),
        (Problem::linear(1e-4), 2000),
        (Problem::linear(1e-6), 500),
        (Problem::linear(1e-6), 1000),
        (Problem::linear(1e-6), 2000),
        (Problem::linear(1e-6), 4000),
        (Problem::multi_mode(MODE_MASSES), 2000),
        (Problem::multi_mode(MODE_MASSES), 4000),
        (Problem::multi_mode([9e-7, 9e-8, 1e-8]), 2000),
        (Problem::rotation_cap(1e-4), 2000),
        (Problem::rotation_cap(1e-4), 4000),
    ];
    for (i, (problem, particles)) in rows.iter().enumerate() {
        let config = with_particles(*particles);
        let s = study(problem, &config, 1000, 1_000_000 * (i as u64 + 1));
        print_study(problem, &config, &s);
    }
}
