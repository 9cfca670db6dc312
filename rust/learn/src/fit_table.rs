//! One row per instance and pose fit, the columns of `eval_geometry.parquet` and `eval.parquet`
//! (schema `EVAL_GEOMETRY` and `EVAL`, documented there) as every writer fills them: `boxpose
//! eval-geometry`, `boxpose eval` and the scoring of another system (`eval --sut`). No burn.

use std::sync::Arc;

use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, StringArray,
};
use boxpose_geometry::pipeline::{FitOutcome, Method, Scores};

/// scene_id, frame_id, object_id: one box of a dataset.
pub type InstanceKey = (i64, i32, i32);

/// One instance and one pose fit of it.
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
pub fn leading_columns(rows: &[(InstanceKey, &str, f64, Option<&Scores>)]) -> Vec<ArrayRef> {
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

#[cfg(test)]
mod tests {
    use super::{FitRow, columns};
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
}
