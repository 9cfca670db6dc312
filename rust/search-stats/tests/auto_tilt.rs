//! `--ce-tilt auto` validated on analytic failure sets in the `single_box` shape (one
//! orientation block z[0..4] and 14 scalars): the tests of the first iteration's elites find the
//! dimensions the failure depends on, the interval still covers, and holding the others at the
//! nominal costs no evaluations against tilting everything (the measured saving is printed).

mod common;

use boxpose_search_stats::{
    CeConfig, CeRun, Proposal, TiltChoice, normal_quantile, run_in_memory_auto_tilt,
    run_in_memory_from,
};
use common::analytic::{binomial_acceptance, monte_carlo_evaluations, rotation_angle_for};

const DIM: usize = 18;
const BLOCKS: [usize; 1] = [0];
const ALPHA: f64 = 0.01;

/// A failure set of known probability p that depends on a few dimensions only.
#[derive(Clone, Copy)]
enum Failure {
    /// (z[5] − z[11])/√2 ≥ Φ⁻¹(1 − p).
    Linear,
    /// The orientation within ω0 of a fixed one (probability 0.02) and z[7] ≥ Φ⁻¹(1 − p/0.02).
    RotationAndParameter,
}

impl Failure {
    fn relevant(self) -> Vec<usize> {
        match self {
            Failure::Linear => vec![5, 11],
            Failure::RotationAndParameter => vec![0, 7],
        }
    }

    fn score(self, p: f64) -> impl Fn(&[f64]) -> f64 {
        let level = normal_quantile(1.0 - p);
        let cap = 0.02;
        let z_level = normal_quantile(1.0 - p / cap);
        let cos_half = (0.5 * rotation_angle_for(cap)).cos();
        let q0 = {
            let q = [0.5f64, -0.3, 0.7, 0.4];
            let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
            q.map(|x| x / n)
        };
        move |z: &[f64]| match self {
            Failure::Linear => (z[5] - z[11]) / 2f64.sqrt() - level,
            Failure::RotationAndParameter => {
                let n = z[..4].iter().map(|x| x * x).sum::<f64>().sqrt();
                let dot = q0.iter().zip(&z[..4]).map(|(a, b)| a * b).sum::<f64>() / n;
                (5.0 * (dot.abs() - cos_half)).min(z[7] - z_level)
            }
        }
    }
}

fn config(failure: Failure) -> CeConfig {
    CeConfig {
        samples_per_iteration: 500,
        max_iterations: 30,
        rho: 0.9,
        alpha: 0.9,
        defensive_lambda: 0.2,
        final_samples: match failure {
            Failure::Linear => 2000,
            Failure::RotationAndParameter => 5000,
        },
        components: 1,
        min_std: 0.75,
    }
}

struct Measured {
    covered: u64,
    mean_evaluations: f64,
    relative_rmse: f64,
}

impl Measured {
    /// Evaluations for a 10 % relative error: tuning + final × (relative RMSE / 0.1)².
    fn for_10pct(&self, final_samples: usize) -> f64 {
        let tuning = self.mean_evaluations - final_samples as f64;
        tuning + final_samples as f64 * (self.relative_rmse / 0.1).powi(2)
    }
}

fn measure(p: f64, reps: u64, mut run: impl FnMut(u64) -> CeRun) -> Measured {
    let (mut covered, mut evaluations, mut sq) = (0, 0.0, 0.0);
    for seed in 0..reps {
        let r = run(seed);
        if r.estimate.ci95.is_some_and(|(lo, hi)| lo <= p && p <= hi) {
            covered += 1;
        }
        evaluations += (r.tuning_evaluations + r.estimate.samples) as f64;
        sq += ((r.estimate.p_hat - p) / p).powi(2);
    }
    Measured {
        covered,
        mean_evaluations: evaluations / reps as f64,
        relative_rmse: (sq / reps as f64).sqrt(),
    }
}

fn tilted_starts(choice: &TiltChoice) -> Vec<usize> {
    choice
        .tests
        .iter()
        .filter(|t| t.tilted)
        .map(|t| t.start)
        .collect()
}

fn compare(failure: Failure, p: f64, reps: u64) {
    let config = config(failure);
    let score = failure.score(p);
    let mut exact = 0;
    let auto = measure(p, reps, |seed| {
        let (run, choice) =
            run_in_memory_auto_tilt(&config, DIM, &BLOCKS, 100 + seed, 0.0, ALPHA, &score)
                .expect("auto-tilt run");
        exact += (tilted_starts(&choice) == failure.relevant()) as u64;
        run
    });
    let start = Proposal::tuning_start(DIM, 1)
        .with_rotation_blocks(&BLOCKS)
        .unwrap();
    let all = measure(p, reps, |seed| {
        run_in_memory_from(&config, &start, 100 + seed, 0.0, &score).expect("ce run")
    });
    let mc = monte_carlo_evaluations(p);
    let (auto_10, all_10) = (
        auto.for_10pct(config.final_samples),
        all.for_10pct(config.final_samples),
    );
    println!(
        "p = {p:e}: auto tilt chose exactly the failure's dimensions in {exact}/{reps}; \
         covered {}/{reps} (all tilted {}/{reps}); evaluations for 10 % RE {auto_10:.0} \
         ({:.1}× fewer than MC) against {all_10:.0} tilting all ({:.1}×)",
        auto.covered,
        all.covered,
        mc / auto_10,
        mc / all_10
    );
    let (lo, hi) = binomial_acceptance(reps, 0.95, 0.01);
    assert!(
        (lo..=hi).contains(&auto.covered),
        "coverage {}/{reps} outside [{lo}, {hi}]",
        auto.covered
    );
    assert!(
        exact as f64 >= 0.9 * reps as f64,
        "chose exactly the failure's dimensions in only {exact}/{reps}"
    );
    assert!(
        auto_10 <= all_10,
        "auto tilt needs {auto_10:.0} evaluations, tilting all {all_10:.0}"
    );
}

#[test]
fn auto_tilt_finds_a_linear_failure_s_two_dimensions() {
    compare(Failure::Linear, 1e-3, 100);
}

#[test]
fn auto_tilt_finds_an_orientation_block_and_a_parameter() {
    compare(Failure::RotationAndParameter, 1e-3, 100);
}

#[test]
fn auto_tilt_at_1e4() {
    compare(Failure::Linear, 1e-4, 100);
    compare(Failure::RotationAndParameter, 1e-4, 100);
}
