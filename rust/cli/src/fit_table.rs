//! One row per instance and pose fit, as `eval-geometry` and `eval` write and summarize them.

use std::sync::Arc;

use arrow::array::{ArrayRef, Float64Array, Int32Array, Int64Array, StringArray};
use arrow::datatypes::{DataType, Field};
use boxpose_geometry::pipeline::{Method, Scores};

pub struct FitRow {
    pub scene_id: i64,
    pub frame_id: i32,
    pub object_id: i32,
    pub method: Method,
    pub diameter_m: f64,
    pub outcome: Result<Scores, String>,
}

pub fn fields() -> Vec<Field> {
    let f64_field = |name: &str| Field::new(name, DataType::Float64, true);
    vec![
        Field::new("scene_id", DataType::Int64, false),
        Field::new("frame_id", DataType::Int32, false),
        Field::new("object_id", DataType::Int32, false),
        Field::new("method", DataType::Utf8, false),
        Field::new("diameter_m", DataType::Float64, false),
        f64_field("paper_error"),
        f64_field("mssd_m"),
        f64_field("add_s_m"),
        f64_field("rotation_error_deg"),
        f64_field("translation_error_m"),
        f64_field("fit_time_us"),
        Field::new("fit_error", DataType::Utf8, true),
    ]
}

/// The columns of [`fields`], in order.
pub fn columns(rows: &[FitRow]) -> Vec<ArrayRef> {
    let metric = |get: fn(&Scores) -> f64| -> ArrayRef {
        Arc::new(rows.iter().map(|r| r.outcome.as_ref().ok().map(get)).collect::<Float64Array>())
    };
    vec![
        Arc::new(rows.iter().map(|r| r.scene_id).collect::<Int64Array>()),
        Arc::new(rows.iter().map(|r| r.frame_id).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| r.object_id).collect::<Int32Array>()),
        Arc::new(rows.iter().map(|r| Some(r.method.name())).collect::<StringArray>()),
        Arc::new(rows.iter().map(|r| r.diameter_m).collect::<Float64Array>()),
        metric(|s| s.paper_error),
        metric(|s| s.mssd_m),
        metric(|s| s.add_s_m),
        metric(|s| s.rotation_error_deg),
        metric(|s| s.translation_error_m),
        metric(|s| s.fit_time_us),
        Arc::new(rows.iter().map(|r| r.outcome.as_ref().err().map(String::as_str)).collect::<StringArray>()),
    ]
}

/// A table per method: recall of MSSD below 5 % and 10 % of the diameter (failed fits count as
/// misses), median MSSD, mean paper error, mean fit time.
pub fn print(rows: &[FitRow]) {
    println!("{:<14} {:>9} {:>11} {:>11} {:>13} {:>13} {:>12}", "method", "instances", "MSSD<0.05d", "MSSD<0.1d", "median MSSD", "mean error", "mean time");
    for method in Method::ALL {
        let of_method: Vec<&FitRow> = rows.iter().filter(|r| r.method == method).collect();
        let scored: Vec<(&Scores, f64)> = of_method.iter().filter_map(|r| r.outcome.as_ref().ok().map(|s| (s, r.diameter_m))).collect();
        let name = method.name();
        if scored.is_empty() {
            println!("{name:<14} {:>9} every fit failed", of_method.len());
            continue;
        }
        let total = of_method.len() as f64;
        let recall = |fraction: f64| scored.iter().filter(|(s, d)| s.mssd_m < fraction * d).count() as f64 / total;
        let mut mssd: Vec<f64> = scored.iter().map(|(s, _)| s.mssd_m).collect();
        mssd.sort_by(f64::total_cmp);
        let n = scored.len() as f64;
        println!(
            "{name:<14} {:>9} {:>10.1}% {:>10.1}% {:>11.4} m {:>13.6} {:>9.0} µs",
            of_method.len(),
            100.0 * recall(0.05),
            100.0 * recall(0.1),
            mssd[mssd.len() / 2],
            scored.iter().map(|(s, _)| s.paper_error).sum::<f64>() / n,
            scored.iter().map(|(s, _)| s.fit_time_us).sum::<f64>() / n,
        );
    }
}
