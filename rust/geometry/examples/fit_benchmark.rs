//! Failure rate by outlier count and noise for every fit on the crate's seeded benchmark set
//! ([`boxpose_geometry::benchmark`]), with per-box time and the AUROC of each fit's confidence
//! as a failure predictor. The tables of `docs/benchmarks.md` (Geometry).
//!
//! cargo run --release -p boxpose-geometry --example fit_benchmark -- [BOXES_PER_CELL] [fits]
//!
//! `fits` is a comma-separated subset of: oracle, fast_exact, robust, size_and_pose, robust_fixed,
//! size_and_pose_ls, and `robust+depth`, `size_and_pose+depth`: the fit whose mirror ties are then
//! settled with the true box's depth image ([`benchmark::Case::depth_image`]; the check is counted
//! in the time, the rendering is not).

use std::time::Instant;

use boxpose_geometry::benchmark::{self, Case, Outliers, Shape, WRONG_FRACTION_OF_DIAMETER};
use boxpose_geometry::metrics;
use boxpose_geometry::pipeline::{Method, fit_method};

/// A row of the tables: the oracle (`None`), or a fit, with or without the depth image.
type Fit = Option<(Method, bool)>;

fn name(fit: Fit) -> String {
    match fit {
        None => "oracle".to_string(),
        Some((method, false)) => method.name().to_string(),
        Some((method, true)) => format!("{}+depth", method.name()),
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let per_cell: usize = args
        .next()
        .map(|s| s.parse().expect("a count"))
        .unwrap_or(1000);
    // `None` is the oracle: least squares on the true inliers with their true corners.
    let methods: Vec<Fit> = match args.next() {
        Some(list) => list
            .split(',')
            .map(|wanted| {
                (wanted != "oracle").then(|| {
                    let (method_name, depth) = match wanted.strip_suffix("+depth") {
                        Some(base) => (base, true),
                        None => (wanted, false),
                    };
                    let method = *Method::ALL
                        .iter()
                        .find(|m| m.name() == method_name)
                        .unwrap_or_else(|| panic!("unknown fit {wanted}"));
                    (method, depth)
                })
            })
            .collect(),
        None => std::iter::once(None)
            .chain(
                Method::ALL
                    .into_iter()
                    .filter(|m| *m != Method::PaperExact)
                    .map(|m| Some((m, false))),
            )
            .chain([
                Some((Method::Robust, true)),
                Some((Method::SizeAndPose, true)),
            ])
            .collect(),
    };
    let noises = [0.001, 0.003, 0.01, 0.02];
    for method in methods {
        println!(
            "\n## {} ({} boxes per cell, shapes cube/square/plate/generic in turn)",
            name(method),
            per_cell
        );
        println!(
            "{:<12} {:>3} | {:>8} {:>8} {:>8} {:>8} | {:>9} {:>9}",
            "outliers", "k", "1 mm", "3 mm", "1 cm", "2 cm", "µs/box", "AUROC≤1cm"
        );
        let mut all_time = 0.0;
        let mut all_boxes = 0usize;
        for kind in Outliers::ALL {
            for k in 0..=4 {
                if k == 0 && kind != Outliers::Uniform {
                    continue;
                }
                let mut cells = Vec::new();
                let mut outcomes = Vec::new();
                let mut time = 0.0;
                for (n_index, &noise) in noises.iter().enumerate() {
                    let mut wrong = 0;
                    for (s_index, shape) in Shape::ALL.into_iter().enumerate() {
                        let seed = 1000 * (k as u64 + 1)
                            + 100 * n_index as u64
                            + 10 * s_index as u64
                            + kind as u64;
                        let cases = benchmark::generate(seed, per_cell / 4, shape, k, kind, noise);
                        for case in &cases {
                            let (is_wrong, confidence, seconds) = run(method, case);
                            wrong += is_wrong as usize;
                            time += seconds;
                            if noise <= 0.01 {
                                outcomes.push((is_wrong, confidence));
                            }
                        }
                    }
                    cells.push(100.0 * wrong as f64 / (4 * (per_cell / 4)) as f64);
                }
                let boxes = noises.len() * 4 * (per_cell / 4);
                all_time += time;
                all_boxes += boxes;
                let auroc = boxpose_geometry::metrics::failure_auroc(&outcomes)
                    .map_or("—".to_string(), |a| format!("{a:.3}"));
                println!(
                    "{:<12} {:>3} | {:>7.1}% {:>7.1}% {:>7.1}% {:>7.1}% | {:>9.1} {:>9}",
                    kind.name(),
                    k,
                    cells[0],
                    cells[1],
                    cells[2],
                    cells[3],
                    1e6 * time / boxes as f64,
                    auroc
                );
            }
        }
        println!("mean time {:.1} µs/box", 1e6 * all_time / all_boxes as f64);
    }
}

/// (wrong, confidence, seconds) of one fit on one case; a failed fit is wrong with confidence 0.
fn run(fit: Fit, case: &Case) -> (bool, f64, f64) {
    let Some((method, with_depth)) = fit else {
        let wrong = benchmark::oracle_pose(case).is_none_or(|pose| {
            !(metrics::mssd(&case.model, &pose, &case.truth).unwrap()
                <= WRONG_FRACTION_OF_DIAMETER * case.model.diameter())
        });
        return (wrong, 0.0, 0.0);
    };
    // rendered before the clock starts: the image is the input, not part of the fit
    let image = with_depth.then(|| case.depth_image());
    let start = Instant::now();
    let mut fit = fit_method(method, Some(&case.model), &case.points, &case.scores);
    if let (Ok(fitted), Some(image)) = (&mut fit, &image) {
        fitted.resolve_mirror(&case.points, &image.view());
    }
    let seconds = start.elapsed().as_secs_f64();
    match fit {
        Ok(fit) => {
            let mssd = fit.mssd(&case.model, &case.truth);
            let wrong = !(mssd <= WRONG_FRACTION_OF_DIAMETER * case.model.diameter());
            (
                wrong,
                fit.confidence(&case.points).map_or(0.0, |c| c.confidence),
                seconds,
            )
        }
        Err(_) => (true, 0.0, seconds),
    }
}
