//! `boxpose eval-results bop RESULTS.csv DATASET`: score another method's BOP-format pose results
//! (`scene_id,im_id,obj_id,score,R,t,time`) against a boxpose dataset with the project's metrics.
//! The ids are those `boxpose export bop` wrote: scene_id, im_id = frame_id, and obj_id one per
//! distinct box size (export::object_ids). See docs/export.md, "Scoring other methods' results".

use std::collections::{BTreeMap, HashMap};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array,
};
use boxpose_data::{Dataset, Instance};
use boxpose_geometry::BoxModel;
use boxpose_geometry::align::nearest_rotation;
use boxpose_geometry::metrics;
use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use serde_json::json;

use crate::export;

/// Command-line options of `boxpose eval-results`.
#[derive(clap::Args)]
#[command(
    about = "Score another method's pose results (BOP CSV) on a boxpose dataset with the project's metrics",
    after_help = "Example:\n  \
        boxpose export bop datasets/generated/demo build/bop/demo\n  \
        # … run a BOP method on build/bop/demo, giving results.csv …\n  \
        boxpose eval-results bop results.csv datasets/generated/demo --out results/eval_bop\n\n\
        See docs/export.md, \"Scoring other methods' results\"."
)]
pub struct Args {
    #[command(subcommand)]
    pub format: Format,
}

#[derive(clap::Subcommand)]
pub enum Format {
    /// BOP results CSV: scene_id,im_id,obj_id,score,R,t,time (R row-major, t in mm), with ids as
    /// `boxpose export bop` numbered them.
    Bop(BopArgs),
}

#[derive(clap::Args)]
pub struct BopArgs {
    /// Results CSV (an optional `scene_id,im_id,…` header line is skipped).
    pub results: PathBuf,
    /// The boxpose dataset folder the BOP export was made from.
    pub dataset: PathBuf,
    /// Output folder: eval_results.parquet and summary.json.
    #[arg(long, default_value = "results/eval_results")]
    pub out: PathBuf,
    /// Count and report malformed lines instead of stopping at the first one.
    #[arg(long)]
    pub skip_malformed: bool,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.format {
        Format::Bop(a) => bop(a),
    }
}

/// Largest entry of |R − nearest rotation| a result's R may have.
const ROTATION_TOLERANCE: f64 = 1e-3;

/// One parsed line of the results CSV.
#[derive(Debug, Clone)]
struct Estimate {
    line: usize,
    scene_id: i64,
    im_id: i32,
    obj_id: u32,
    score: f64,
    pose: Isometry3<f64>,
}

/// Parses one data line; `Err` holds the reason (without the line number).
fn parse_line(text: &str) -> Result<(i64, i32, u32, f64, Isometry3<f64>), String> {
    let cols: Vec<&str> = text.split(',').map(str::trim).collect();
    if cols.len() != 7 {
        return Err(format!(
            "expected 7 comma-separated columns (scene_id,im_id,obj_id,score,R,t,time), got {}",
            cols.len()
        ));
    }
    let int = |name: &str, s: &str| {
        s.parse::<i64>()
            .map_err(|_| format!("{name} {s:?} is not an integer"))
    };
    let scene_id = int("scene_id", cols[0])?;
    let im_id = i32::try_from(int("im_id", cols[1])?)
        .map_err(|_| format!("im_id {} is out of range", cols[1]))?;
    let obj_id = u32::try_from(int("obj_id", cols[2])?)
        .map_err(|_| format!("obj_id {} is out of range", cols[2]))?;
    let floats = |name: &str, s: &str, n: usize| -> Result<Vec<f64>, String> {
        let v: Vec<f64> = s
            .split_whitespace()
            .map(|x| {
                x.parse::<f64>()
                    .map_err(|_| format!("{name}: {x:?} is not a number"))
            })
            .collect::<Result<_, _>>()?;
        if v.len() != n {
            return Err(format!("{name} has {} values, expected {n}", v.len()));
        }
        if let Some(x) = v.iter().find(|x| !x.is_finite()) {
            return Err(format!("{name} holds a non-finite value ({x})"));
        }
        Ok(v)
    };
    let score = floats("score", cols[3], 1)?[0];
    let r = floats("R", cols[4], 9)?;
    let t = floats("t", cols[5], 3)?;
    floats("time", cols[6], 1)?;
    let m = Matrix3::from_row_slice(&r);
    if m.determinant() < 0.0 {
        return Err("R is a reflection (determinant < 0), not a rotation".into());
    }
    let nearest = nearest_rotation(&m)
        .ok_or("R is not a rotation: it has rank ≤ 1")?
        .into_inner();
    let off = (m - nearest).abs().max();
    if off > ROTATION_TOLERANCE {
        return Err(format!(
            "R is not a rotation: it differs from the nearest rotation by {off:.3e} (> {ROTATION_TOLERANCE})"
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(nearest));
    let translation = Translation3::new(t[0] / 1000.0, t[1] / 1000.0, t[2] / 1000.0);
    Ok((
        scene_id,
        im_id,
        obj_id,
        score,
        Isometry3::from_parts(translation, rotation),
    ))
}

/// A ground-truth instance with its BOP obj_id.
struct Truth {
    instance: Instance,
    obj_id: u32,
    model: BoxModel,
    pose: Isometry3<f64>,
}

/// Metrics of one matched estimate.
#[derive(Clone, Copy, Default)]
struct Scores {
    cube_mssd: f64,
    mssd: f64,
    add_s: f64,
    paper_error: f64,
    paper_error_normalized: f64,
    rotation_error_deg: f64,
    translation_error: f64,
}

fn score(truth: &Truth, estimate: &Isometry3<f64>) -> anyhow::Result<Scores> {
    let corners: Vec<Point3<f64>> = truth
        .instance
        .corners_camera
        .iter()
        .map(|c| Point3::from(*c))
        .collect();
    let paper_error = metrics::paper_error(&truth.model, estimate, &corners)?;
    let d = truth.model.diameter();
    Ok(Scores {
        cube_mssd: metrics::cube_mssd(&truth.model, estimate, &truth.model, &truth.pose)?,
        mssd: metrics::mssd(&truth.model, estimate, &truth.pose)?,
        add_s: metrics::add_s(&truth.model, estimate, &truth.pose)?,
        paper_error,
        paper_error_normalized: paper_error / (d * d / 3.0),
        rotation_error_deg: metrics::rotation_error_deg(&truth.model, estimate, &truth.pose)?,
        translation_error: metrics::translation_error(estimate, &truth.pose)?,
    })
}

/// One output row: a ground-truth instance and the estimate assigned to it, if any.
struct Row {
    gt: usize,
    matched: Option<(Estimate, Scores)>,
}

fn bop(args: &BopArgs) -> anyhow::Result<()> {
    let _claim = crate::output_folder::claim(
        &args.out,
        "--out",
        "eval-results",
        &["eval_results.parquet"],
    )?;
    let dataset = Dataset::open(&args.dataset)?;
    crate::inspect::warn_if_incomplete(&dataset);
    let ids = export::object_ids(&dataset)?;
    let known_obj: std::collections::BTreeSet<u32> = ids.values().copied().collect();

    // Ground truth, per frame in object_id order (gt_id = rank, as export bop writes it).
    let mut truths: Vec<Truth> = Vec::new();
    let mut frames: HashMap<(i64, i32), Vec<usize>> = HashMap::new();
    for frame in dataset.frames()? {
        let frame = frame?;
        let list = frames.entry((frame.scene_id, frame.frame_id)).or_default();
        for instance in frame.instances {
            let obj_id = export::obj_id(&ids, &instance)?;
            let model = BoxModel::new(Vector3::from(instance.size))?;
            let q = instance.camera_box.quat_wxyz;
            let pose = Isometry3::from_parts(
                Translation3::from(Vector3::from(instance.camera_box.translation)),
                UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3])),
            );
            list.push(truths.len());
            truths.push(Truth {
                instance,
                obj_id,
                model,
                pose,
            });
        }
    }

    // Results.
    let text = fs::read_to_string(&args.results)
        .with_context(|| format!("cannot read {}", args.results.display()))?;
    let name = args.results.display();
    let mut estimates: Vec<Estimate> = Vec::new();
    let mut malformed: Vec<String> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let number = i + 1;
        let trimmed = line.trim();
        if trimmed.is_empty()
            || (estimates.is_empty() && malformed.is_empty() && trimmed.starts_with("scene_id"))
        {
            continue;
        }
        let parsed = parse_line(trimmed).and_then(|(scene_id, im_id, obj_id, score, pose)| {
            if !frames.contains_key(&(scene_id, im_id)) {
                return Err(format!(
                    "scene_id {scene_id} im_id {im_id} is no frame of the dataset"
                ));
            }
            if !known_obj.contains(&obj_id) {
                return Err(format!(
                    "obj_id {obj_id} is unknown (the dataset has obj_ids 1..={})",
                    known_obj.len()
                ));
            }
            Ok(Estimate {
                line: number,
                scene_id,
                im_id,
                obj_id,
                score,
                pose,
            })
        });
        match parsed {
            Ok(e) => estimates.push(e),
            Err(reason) if args.skip_malformed => {
                malformed.push(format!("{name} line {number}: {reason}"))
            }
            Err(reason) => bail!(
                "{name} line {number}: {reason} (pass --skip-malformed to count and skip such lines)"
            ),
        }
    }

    // Matching, per (scene, image, obj_id): estimates by decreasing score, each to the unassigned
    // instance with the smallest cube MSSD, the primary metric (bop_toolkit's per-object greedy
    // matching on the error evaluated, no threshold).
    let mut groups: BTreeMap<(i64, i32, u32), Vec<Estimate>> = BTreeMap::new();
    for e in &estimates {
        groups
            .entry((e.scene_id, e.im_id, e.obj_id))
            .or_default()
            .push(e.clone());
    }
    let mut assigned: HashMap<usize, (Estimate, Scores)> = HashMap::new();
    for ((scene_id, im_id, obj_id), mut group) in groups {
        group.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.line.cmp(&b.line)));
        let candidates: Vec<usize> = frames[&(scene_id, im_id)]
            .iter()
            .copied()
            .filter(|&g| truths[g].obj_id == obj_id)
            .collect();
        for e in group {
            let mut best: Option<(usize, Scores)> = None;
            for &g in candidates.iter().filter(|g| !assigned.contains_key(g)) {
                let s = score(&truths[g], &e.pose)
                    .with_context(|| format!("{name} line {}", e.line))?;
                if best.as_ref().is_none_or(|(_, b)| s.cube_mssd < b.cube_mssd) {
                    best = Some((g, s));
                }
            }
            if let Some((g, s)) = best {
                assigned.insert(g, (e, s));
            }
        }
    }
    let rows: Vec<Row> = (0..truths.len())
        .map(|g| Row {
            gt: g,
            matched: assigned.remove(&g),
        })
        .collect();

    fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    write_rows(&args.out.join("eval_results.parquet"), &rows, &truths)?;

    // Summary.
    let n = rows.len();
    let matched: Vec<&(Estimate, Scores)> =
        rows.iter().filter_map(|r| r.matched.as_ref()).collect();
    // Per row, `error` of its match over the diameter; +∞ for a missed instance.
    let over_diameter = |rows: &[&Row], error: fn(&Scores) -> f64| -> Vec<f64> {
        rows.iter()
            .map(|r| {
                r.matched.as_ref().map_or(f64::INFINITY, |(_, s)| {
                    error(s) / truths[r.gt].model.diameter()
                })
            })
            .collect()
    };
    let recall = |rows: &[&Row], error: fn(&Scores) -> f64, k: f64| {
        if rows.is_empty() {
            f64::NAN
        } else {
            let errors = over_diameter(rows, error);
            errors.iter().filter(|&&e| e < k).count() as f64 / rows.len() as f64
        }
    };
    let mean = |f: fn(&Scores) -> f64| {
        if matched.is_empty() {
            None
        } else {
            Some(matched.iter().map(|(_, s)| f(s)).sum::<f64>() / matched.len() as f64)
        }
    };
    let all: Vec<&Row> = rows.iter().collect();
    let summary = json!({
        "results": args.results.display().to_string(),
        "dataset": args.dataset.display().to_string(),
        "result_lines": estimates.len() + malformed.len(),
        "results_valid": estimates.len(),
        "results_matched": matched.len(),
        "results_unmatched": estimates.len() - matched.len(),
        "malformed_lines": malformed.len(),
        "malformed": malformed,
        "instances": n,
        "instances_matched": matched.len(),
        "instances_missed": n - matched.len(),
        "recall_cube_mssd_0.05d": recall(&all, |s| s.cube_mssd, 0.05),
        "recall_cube_mssd_0.1d": recall(&all, |s| s.cube_mssd, 0.1),
        "recall_mssd_0.05d": recall(&all, |s| s.mssd, 0.05),
        "recall_mssd_0.1d": recall(&all, |s| s.mssd, 0.1),
        "ar_cube_mssd": metrics::average_recall(&over_diameter(&all, |s| s.cube_mssd)),
        "ar_mssd": metrics::average_recall(&over_diameter(&all, |s| s.mssd)),
        "mean_over_matched": {
            "cube_mssd_m": mean(|s| s.cube_mssd),
            "mssd_m": mean(|s| s.mssd),
            "add_s_m": mean(|s| s.add_s),
            "paper_error_m2": mean(|s| s.paper_error),
            "paper_error_normalized": mean(|s| s.paper_error_normalized),
            "rotation_error_deg": mean(|s| s.rotation_error_deg),
            "translation_error_m": mean(|s| s.translation_error),
        },
    });
    let summary_text = serde_json::to_string_pretty(&summary)? + "\n";
    boxpose_data::write_file_atomically(
        &args.out.join("summary.json"),
        summary_text.replace("NaN", "null").as_bytes(),
    )?;

    // Table: one row per obj_id and the total.
    println!(
        "{} result lines: {} valid, {} malformed; {} instances, {} matched, {} missed; {} results unmatched",
        estimates.len() + malformed.len(),
        estimates.len(),
        malformed.len(),
        n,
        matched.len(),
        n - matched.len(),
        estimates.len() - matched.len()
    );
    for m in &malformed {
        println!("  skipped {m}");
    }
    println!(
        "{:>8} {:>9} {:>8} {:>12} {:>11} {:>12} {:>13} {:>9}",
        "obj_id",
        "instances",
        "matched",
        "cube@0.05d",
        "cube@0.1d",
        "MSSD@0.1d",
        "MSSD mm",
        "e_R deg"
    );
    let mut per_obj: BTreeMap<Option<u32>, Vec<&Row>> = BTreeMap::new();
    for r in &rows {
        per_obj
            .entry(Some(truths[r.gt].obj_id))
            .or_default()
            .push(r);
        per_obj.entry(None).or_default().push(r);
    }
    let mut order: Vec<_> = per_obj.keys().copied().filter(Option::is_some).collect();
    order.push(None);
    for key in order {
        let group = &per_obj[&key];
        let hits: Vec<&Scores> = group
            .iter()
            .filter_map(|r| r.matched.as_ref().map(|(_, s)| s))
            .collect();
        let avg = |f: fn(&Scores) -> f64| {
            if hits.is_empty() {
                "-".to_string()
            } else {
                format!(
                    "{:.2}",
                    hits.iter().map(|s| f(s)).sum::<f64>() / hits.len() as f64
                )
            }
        };
        println!(
            "{:>8} {:>9} {:>8} {:>12.3} {:>11.3} {:>12.3} {:>13} {:>9}",
            key.map_or("all".to_string(), |k| k.to_string()),
            group.len(),
            hits.len(),
            recall(group, |s| s.cube_mssd, 0.05),
            recall(group, |s| s.cube_mssd, 0.1),
            recall(group, |s| s.mssd, 0.1),
            avg(|s| s.mssd * 1000.0),
            avg(|s| s.rotation_error_deg)
        );
    }
    println!(
        "per-instance metrics: {}",
        args.out.join("eval_results.parquet").display()
    );
    Ok(())
}

fn write_rows(path: &Path, rows: &[Row], truths: &[Truth]) -> anyhow::Result<()> {
    let truth = |r: &Row| &truths[r.gt];
    // gt_id: the instance's rank in its frame (export bop's order).
    let mut rank: HashMap<(i64, i32), i32> = HashMap::new();
    let gt_ids: Vec<i32> = rows
        .iter()
        .map(|r| {
            let i = &truth(r).instance;
            let n = rank.entry((i.scene_id, i.frame_id)).or_default();
            *n += 1;
            *n - 1
        })
        .collect();
    let metric = |f: fn(&Scores) -> f64| {
        Arc::new(
            rows.iter()
                .map(|r| r.matched.as_ref().map(|(_, s)| f(s)))
                .collect::<Float64Array>(),
        ) as ArrayRef
    };
    let columns: Vec<ArrayRef> = vec![
        Arc::new(
            rows.iter()
                .map(|r| truth(r).instance.scene_id)
                .collect::<Int64Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| truth(r).instance.frame_id)
                .collect::<Int32Array>(),
        ),
        Arc::new(Int32Array::from(gt_ids)),
        Arc::new(
            rows.iter()
                .map(|r| truth(r).instance.object_id)
                .collect::<Int32Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| truth(r).obj_id as i32)
                .collect::<Int32Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| truth(r).instance.visible_fraction)
                .collect::<Float32Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| Some(truth(r).model.diameter()))
                .collect::<Float64Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| Some(r.matched.is_some()))
                .collect::<BooleanArray>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| r.matched.as_ref().map(|(e, _)| e.line as i64))
                .collect::<Int64Array>(),
        ),
        Arc::new(
            rows.iter()
                .map(|r| r.matched.as_ref().map(|(e, _)| e.score))
                .collect::<Float64Array>(),
        ),
        metric(|s| s.mssd),
        metric(|s| s.cube_mssd),
        metric(|s| s.add_s),
        metric(|s| s.paper_error),
        metric(|s| s.paper_error_normalized),
        metric(|s| s.rotation_error_deg),
        metric(|s| s.translation_error),
    ];
    boxpose_data::write_table(path, &boxpose_data::schema::EVAL_RESULTS, columns)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_line_and_rejects_bad_ones() {
        let (s, i, o, score, pose) = parse_line("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,-1").unwrap();
        assert_eq!((s, i, o, score), (1, 2, 3, 0.5));
        assert!((pose.translation.vector - Vector3::new(0.01, 0.02, 0.03)).norm() < 1e-12);
        assert!(
            parse_line("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30")
                .unwrap_err()
                .contains("7")
        );
        assert!(
            parse_line("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 NaN 30,-1")
                .unwrap_err()
                .contains("non-finite")
        );
        assert!(
            parse_line("1,2,3,0.5,1 0 0 0 1 0 0 0 1.01,10 20 30,-1")
                .unwrap_err()
                .contains("not a rotation")
        );
        assert!(
            parse_line("1,2,3,0.5,1 0 0 0 1 0 0 0 -1,10 20 30,-1")
                .unwrap_err()
                .contains("reflection")
        );
    }
}
