//! Cross-entropy against Monte Carlo on the analytic failure functions of the validation suite:
//! evaluations to a 10 % relative standard error (tuning included) and 95 % interval coverage.
//!
//! `cargo run --release -p boxpose-search-stats --example estimator_bench`

#[path = "../tests/common/analytic.rs"]
mod analytic;

use analytic::{Problem, binomial_acceptance, monte_carlo_evaluations, repeat};

const REPS: u64 = 100;

fn main() {
    let (lo, hi) = binomial_acceptance(REPS, 0.95, 0.01);
    println!(
        "{REPS} seeded runs per row; coverage acceptance region (two-sided binomial, 1 %): [{lo}, {hi}]"
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
        let r = repeat(problem, &config, REPS, 100_000 * (i as u64 + 1));
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
