//! One row per instance and pose fit, as `eval-geometry` and `eval` write and summarize them.

use std::sync::Arc;

use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, StringArray,
};
use boxpose_geometry::metrics::average_recall;
use boxpose_geometry::pipeline::{FitOutcome, Method, Scores};
use boxpose_search::compare::BoxKey;

pub struct FitRow {
    pub scene_id: i64,
    pub frame_id: i32,
    pub object_id: i32,
    pub method: Method,
    pub diameter_m: f64,
    pub outcome: FitOutcome,
}

/// The first twelve columns of a fit table, which every writer fills alike: the box's keys, the
/// method, the diameter and the seven distances of its pose (null where no pose came back, and
/// where a value is not finite, which the readers refuse).
pub fn leading_columns(rows: &[(BoxKey, &str, f64, Option<&Scores>)]) -> Vec<ArrayRef> {
    let metric = |get: fn(&Scores) -> f64| -> ArrayRef {
        Arc::new(
            rows.iter()
                .map(|(_, _, _, scores)| scores.map(get).filter(|v| v.is_finite()))
                .collect::<Float64Array>(),
        )
    };
    vec![
        Arc::new(rows.iter().map(|r| r.0.0).collect::<Int64Array>()),
        Arc::new(rows.iter().map(|r| r.0.1).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.0.2).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| Some(r.1)).collect::<StringArray>()),
        Arc::new(rows.iter().map(|r| r.2).collect::<Float64Array>()),
        metric(|s| s.paper_error),
        metric(|s| s.mssd_m),
        metric(|s| s.cube_mssd_m),
        metric(|s| s.iou_3d),
        metric(|s| s.add_s_m),
        metric(|s| s.rotation_error_deg),
        metric(|s| s.translation_error_m),
    ]
}

/// The columns of [`boxpose_data::schema::EVAL_GEOMETRY`] (documented there), in order.
pub fn columns(rows: &[FitRow]) -> Vec<ArrayRef> {
    let metric = |get: fn(&Scores) -> f64| -> ArrayRef {
        Arc::new(
            rows.iter()
                .map(|r| r.outcome.scores().map(get))
                .collect::<Float64Array>(),
        )
    };
    let leading: Vec<_> = rows
        .iter()
        .map(|r| {
            (
                (r.scene_id, r.frame_id, r.object_id),
                r.method.name(),
                r.diameter_m,
                r.outcome.scores(),
            )
        })
        .collect();
    let mut columns = leading_columns(&leading);
    let rest: Vec<ArrayRef> = vec![
        metric(|s| s.fit_time_us),
        metric(|s| s.confidence),
        // no other box hypothesis: an infinite margin, written as null (the readers refuse ±∞)
        Arc::new(
            rows.iter()
                .map(|r| {
                    let margin = r.outcome.scores()?.margin_nats;
                    margin.is_finite().then_some(margin)
                })
                .collect::<Float64Array>(),
        ),
        metric(|s| s.noise_scale_m),
        Arc::new(
            rows.iter()
                .map(|r| r.outcome.scores().map(|s| s.inliers as i32))
                .collect::<Int32Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| r.outcome.scores().map(|s| s.mirror_ambiguous))
                .collect::<BooleanArray>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| r.outcome.failure())
                .collect::<StringArray>(),
        ),
    ];
    columns.extend(rest);
    columns
}

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
        let judged: Vec<(f64, bool)> = scored
            .iter()
            .map(|(s, d)| (s.confidence, s.cube_mssd_m >= 0.1 * d))
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

/// The AUROC of confidence as a predictor of failure, from (confidence, failed) pairs: the
/// probability that a failed fit has a lower confidence than a right one, ties counting half
/// (Mann–Whitney U over mid-ranks). `None` when either class is empty.
pub fn failure_auroc(fits: &[(f64, bool)]) -> Option<f64> {
    let failed = fits.iter().filter(|(_, f)| *f).count();
    let right = fits.len() - failed;
    if failed == 0 || right == 0 {
        return None;
    }
    // Ranks by descending confidence: a failure ranked high (low confidence) is a good prediction.
    let mut order: Vec<usize> = (0..fits.len()).collect();
    order.sort_by(|&a, &b| fits[b].0.total_cmp(&fits[a].0));
    let mut rank_sum = 0.0;
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && fits[order[j + 1]].0 == fits[order[i]].0 {
            j += 1;
        }
        let mid_rank = (i + j) as f64 / 2.0 + 1.0;
        rank_sum += mid_rank * order[i..=j].iter().filter(|&&k| fits[k].1).count() as f64;
        i = j + 1;
    }
    let (failed, right) = (failed as f64, right as f64);
    Some((rank_sum - failed * (failed + 1.0) / 2.0) / (failed * right))
}

#[cfg(test)]
mod tests {
    use super::{FitRow, columns, failure_auroc};
    use boxpose_data::arrow::array::Array;
    use boxpose_geometry::pipeline::{FitOutcome, Method, Scores};

    #[test]
    fn an_infinite_margin_is_written_as_null_and_the_table_reads_back() {
        let scores = |margin_nats| Scores {
            paper_error: 0.01,
            mssd_m: 0.002,
            cube_mssd_m: 0.002,
            iou_3d: 0.95,
            add_s_m: 0.001,
            rotation_error_deg: 0.5,
            translation_error_m: 0.001,
            fit_time_us: 10.0,
            confidence: 0.5,
            margin_nats,
            noise_scale_m: 0.003,
            inliers: 8,
            mirror_ambiguous: false,
            fitted_corners: [[0.0; 3]; 8],
        };
        let rows: Vec<FitRow> = [f64::INFINITY, 10.0]
            .into_iter()
            .enumerate()
            .map(|(i, margin)| FitRow {
                scene_id: 0,
                frame_id: 0,
                object_id: i as i32,
                method: Method::Robust,
                diameter_m: 0.2,
                outcome: FitOutcome::Scored(scores(margin)),
            })
            .collect();
        let path =
            std::env::temp_dir().join(format!("boxpose-fit-table-{}.parquet", std::process::id()));
        let table = &boxpose_data::schema::EVAL_GEOMETRY;
        boxpose_data::write_table(&path, table, columns(&rows)).unwrap();
        // the dataset reader refuses ±inf: the table must pass its checks
        let batches = boxpose_data::read_shard(&path, table).unwrap();
        let margin = batches[0]
            .column_by_name("margin_nats")
            .unwrap()
            .as_any()
            .downcast_ref::<boxpose_data::arrow::array::Float64Array>()
            .unwrap()
            .clone();
        std::fs::remove_file(&path).unwrap();
        assert!(margin.is_null(0));
        assert_eq!(margin.value(1), 10.0);
    }

    #[test]
    fn auroc_of_confidence_as_a_failure_predictor() {
        // every failure less confident than every right fit: 1; the reverse: 0
        assert_eq!(
            failure_auroc(&[(0.1, true), (0.2, true), (0.8, false), (0.9, false)]),
            Some(1.0)
        );
        assert_eq!(failure_auroc(&[(0.9, true), (0.1, false)]), Some(0.0));
        // all tied: chance
        assert_eq!(
            failure_auroc(&[(0.5, true), (0.5, false), (0.5, false)]),
            Some(0.5)
        );
        // one of the two failures below the right fit, one tied with it: (1 + ½) / 2
        assert_eq!(
            failure_auroc(&[(0.2, true), (0.7, true), (0.7, false)]),
            Some(0.75)
        );
        assert_eq!(failure_auroc(&[(0.2, false), (0.7, false)]), None);
    }
}
