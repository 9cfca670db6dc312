//! Cross-entropy against Monte Carlo on the analytic failure functions of the validation suite:
//! evaluations to a 10 % relative standard error (tuning included) and 95 % interval coverage.
//!
//! `CARGO_TARGET_DIR=/tmp/stats-target cargo run --release -p boxpose-search-stats --example estimator_bench [-- RUNS]`
//!
//! The rotation problem tunes from `Proposal::tuning_start(10, 1).with_rotation_blocks(&[0])`
//! (z[0..4] an ACG-direction rotation block), see `Problem::start`.

#[path = "../tests/common/analytic.rs"]
mod analytic;

use analytic::{Problem, binomial_acceptance, monte_carlo_evaluations, repeat};

/// Seeded runs per row unless the first argument gives another number (e.g. `-- 500`).
const REPS: u64 = 100;

fn main() {
    let reps: u64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("runs per row: a positive integer"))
        .unwrap_or(REPS);
    let (lo, hi) = binomial_acceptance(reps, 0.95, 0.01);
    println!(
        "{reps} seeded runs per row; coverage acceptance region (two-sided binomial, 1 %): [{lo}, {hi}]"
    );
    println!(
        "| failure set | p | CE tuning | CE final batch | CE evaluations to 10 % RE | MC (1−p)/(0.01p) | ratio | rel. RMSE / median reported RE | 95 % CI coverage |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for (i, problem) in [
        Problem::linear(1e-2),
        Problem::linear(1e-3),
        Problem::linear(1e-4),
        Problem::rotation(1e-2),
        Problem::rotation(1e-3),
        Problem::rotation(1e-4),
    ]
    .iter()
    .enumerate()
    {
        let config = problem.config();
        let r = repeat(problem, &config, reps, 100_000 * (i as u64 + 1));
        let ce = r.evaluations_for_10pct();
        let mc = monte_carlo_evaluations(problem.p);
        println!(
            "| {} | {:e} | {:.0} | {} | {:.0} | {:.0} | {:.1}× | {:.3} / {:.3} | {}/{}{} |",
            problem.name(),
            problem.p,
            r.mean_tuning,
            r.final_samples,
            ce,
            mc,
            mc / ce,
            r.empirical_relative_rmse,
            r.median_reported_re,
            r.covered,
            r.reps,
            if (lo..=hi).contains(&r.covered) {
                ""
            } else {
                " (outside)"
            }
        );
    }
}
