//! The table `eval-geometry` and `eval` print of their fit rows (`boxpose_learn::fit_table`).

use boxpose_geometry::metrics::{average_recall, failure_auroc};
use boxpose_geometry::pipeline::{Method, Scores};
use boxpose_learn::fit_table::FitRow;

/// A table per method: recall of the cube-group MSSD (the primary metric) below 5 % and 10 % of
/// the diameter and its BOP average recall, recall of the exact-symmetry MSSD below 10 % (failed
/// fits count as misses), median cube MSSD, mean paper error, mean fit time, mean confidence, and
/// the AUROC of the confidence as a predictor of failure (cube MSSD ≥ 0.1 × diameter) over the
/// fits that returned a pose ("—" when they are all right or all wrong).
pub fn print(rows: &[FitRow]) {
    let width = Method::ALL
        .iter()
        .map(|m| m.name().len())
        .max()
        .unwrap_or(0)
        .max("method".len());
    println!(
        "{:<width$} {:>9} {:>11} {:>11} {:>8} {:>11} {:>13} {:>13} {:>12} {:>10} {:>10}",
        "method",
        "instances",
        "cube<0.05d",
        "cube<0.1d",
        "AR cube",
        "MSSD<0.1d",
        "median cube",
        "mean error",
        "mean time",
        "mean conf",
        "conf AUROC"
    );
    for method in Method::ALL {
        let of_method: Vec<&FitRow> = rows.iter().filter(|r| r.method == method).collect();
        let scored: Vec<(&Scores, f64)> = of_method
            .iter()
            .filter_map(|r| r.outcome.scores().map(|s| (s, r.diameter_m)))
            .collect();
        let name = method.name();
        if scored.is_empty() {
            println!("{name:<width$} {:>9} every fit failed", of_method.len());
            continue;
        }
        // Over every row of the method, a failed fit an infinite error (a miss at any threshold).
        let over_diameter = |metric: fn(&Scores) -> f64| -> Vec<f64> {
            of_method
                .iter()
                .map(|r| {
                    r.outcome
                        .scores()
                        .map_or(f64::INFINITY, |s| metric(s) / r.diameter_m)
                })
                .collect()
        };
        let cube = over_diameter(|s| s.cube_mssd_m);
        let exact = over_diameter(|s| s.mssd_m);
        let recall = |errors: &[f64], fraction: f64| {
            100.0 * errors.iter().filter(|&&e| e < fraction).count() as f64 / errors.len() as f64
        };
        let mut median: Vec<f64> = scored.iter().map(|(s, _)| s.cube_mssd_m).collect();
        median.sort_by(f64::total_cmp);
        let n = scored.len() as f64;
        let judged: Vec<(bool, f64)> = scored
            .iter()
            .map(|(s, d)| (s.cube_mssd_m >= 0.1 * d, s.confidence))
            .collect();
        let auroc = failure_auroc(&judged).map_or("—".to_string(), |a| format!("{a:.3}"));
        println!(
            "{name:<width$} {:>9} {:>10.1}% {:>10.1}% {:>7.1}% {:>10.1}% {:>11.4} m {:>13.6} {:>9.0} µs {:>10.3} {:>10}",
            of_method.len(),
            recall(&cube, 0.05),
            recall(&cube, 0.1),
            100.0 * average_recall(&cube),
            recall(&exact, 0.1),
            median[median.len() / 2],
            scored.iter().map(|(s, _)| s.paper_error).sum::<f64>() / n,
            scored.iter().map(|(s, _)| s.fit_time_us).sum::<f64>() / n,
            scored.iter().map(|(s, _)| s.confidence).sum::<f64>() / n,
            auroc,
        );
    }
}
