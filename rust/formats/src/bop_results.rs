//! Another method's BOP-format pose results (`scene_id,im_id,obj_id,score,R,t,time`) scored
//! against a boxpose dataset with the project's metrics. The ids are those `write_bop` writes:
//! scene_id, im_id = frame_id, and obj_id one per distinct box size
//! ([`object_ids`](crate::objects::object_ids)). See docs/export.md, "Scoring other methods'
//! results".

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;
use std::sync::Arc;

use boxpose_data::arrow::array::{
    ArrayRef, BooleanArray, Float32Array, Float64Array, Int32Array, Int64Array,
};
use boxpose_data::{Dataset, Instance};
use boxpose_geometry::align::nearest_rotation;
use boxpose_geometry::pipeline::isometry;
use boxpose_geometry::{BoxModel, GeometryError, metrics};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde_json::{Value, json};

use crate::error::{FormatError, Result, io};
use crate::objects::{obj_id, object_ids};

/// Largest entry of |R − nearest rotation| a result's R may have.
const ROTATION_TOLERANCE: f64 = 1e-3;

/// One parsed line of the results CSV.
#[derive(Debug, Clone)]
pub struct Estimate {
    /// 1-based line number in the CSV.
    pub line: usize,
    pub scene_id: i64,
    pub im_id: i32,
    pub obj_id: u32,
    pub score: f64,
    /// Model to camera, metres.
    pub pose: Isometry3<f64>,
}

/// A ground-truth instance with its BOP obj_id.
pub struct Truth {
    pub instance: Instance,
    pub obj_id: u32,
    pub model: BoxModel,
    pub pose: Isometry3<f64>,
    /// Its frame's fx, fy, cx, cy and width (pixels), for MSPD.
    pub intrinsics: [f64; 4],
    pub image_width: usize,
}

/// Metrics of one matched estimate (metres, m², degrees), as in eval.parquet.
#[derive(Debug, Clone, Copy, Default)]
pub struct Scores {
    pub cube_mssd: f64,
    pub mssd: f64,
    pub add_s: f64,
    /// Pixels.
    pub mspd: f64,
    pub paper_error: f64,
    pub paper_error_normalized: f64,
    pub rotation_error_deg: f64,
    pub translation_error: f64,
}

/// A ground-truth instance (index into `truths`) and the estimate assigned to it, if any.
pub struct Row {
    pub gt: usize,
    pub matched: Option<(Estimate, Scores)>,
}

/// Every ground-truth instance of a dataset with the result assigned to it.
pub struct ResultsScore {
    pub truths: Vec<Truth>,
    /// One per truth, in dataset order.
    pub rows: Vec<Row>,
    /// Lines parsed and checked against the dataset.
    pub valid: usize,
    /// "FILE line N: reason" of each line skipped with `skip_malformed`.
    pub malformed: Vec<String>,
}

/// One line of the per-object table: recalls over the group's instances (a missed instance
/// counts as a failure), means over its matched ones.
#[derive(Debug, Clone, Copy)]
pub struct ObjectRecall {
    /// None for all objects together.
    pub obj_id: Option<u32>,
    pub instances: usize,
    pub matched: usize,
    pub cube_mssd_005: f64,
    pub cube_mssd_01: f64,
    pub mssd_01: f64,
    pub mean_mssd_mm: Option<f64>,
    pub mean_rotation_error_deg: Option<f64>,
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

fn score(truth: &Truth, estimate: &Isometry3<f64>) -> Result<Scores, GeometryError> {
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
        mspd: metrics::mspd(&truth.model, estimate, &truth.pose, truth.intrinsics)?,
        paper_error,
        paper_error_normalized: paper_error / (d * d / 3.0),
        rotation_error_deg: metrics::rotation_error_deg(&truth.model, estimate, &truth.pose)?,
        translation_error: metrics::translation_error(estimate, &truth.pose)?,
    })
}

/// Per (scene_id, frame_id), the indices of its instances in the list of truths.
type FrameTruths = HashMap<(i64, i32), Vec<usize>>;

/// The dataset's instances with their obj_ids, and per (scene, frame) their indices in object_id
/// order (gt_id = rank, as `write_bop` numbers them).
fn read_truths(dataset: &Dataset) -> Result<(Vec<Truth>, FrameTruths)> {
    let ids = object_ids(dataset)?;
    let mut truths: Vec<Truth> = Vec::new();
    let mut frames = FrameTruths::new();
    for frame in dataset.frames()? {
        let frame = frame?;
        let list = frames.entry((frame.scene_id, frame.frame_id)).or_default();
        let k = frame.intrinsics;
        for instance in frame.instances {
            let obj_id = obj_id(&ids, &instance)?;
            let model = BoxModel::new(Vector3::from(instance.size)).map_err(|source| {
                FormatError::Geometry {
                    context: format!(
                        "scene {} frame {} object {}",
                        instance.scene_id, instance.frame_id, instance.object_id
                    ),
                    source,
                }
            })?;
            let pose = isometry(
                instance.camera_box.quat_wxyz,
                instance.camera_box.translation,
            );
            list.push(truths.len());
            truths.push(Truth {
                instance,
                obj_id,
                model,
                pose,
                intrinsics: [k.fx, k.fy, k.cx, k.cy],
                image_width: frame.width,
            });
        }
    }
    Ok((truths, frames))
}

/// Scores the BOP results CSV at `results` (an optional `scene_id,…` header line is skipped)
/// against `dataset`. Each line must name a frame of the dataset and a known obj_id; a line that
/// does not, or does not parse, is an error naming it, or with `skip_malformed` is counted in
/// [`ResultsScore::malformed`].
///
/// Matching, per (scene, image, obj_id): estimates by decreasing score, each to the unassigned
/// instance with the smallest cube MSSD, the primary metric (bop_toolkit's per-object greedy
/// matching on the error evaluated, no threshold).
pub fn score_bop_results(
    dataset: &Dataset,
    results: &Path,
    skip_malformed: bool,
) -> Result<ResultsScore> {
    let (truths, frames) = read_truths(dataset)?;
    let known_obj: BTreeSet<u32> = truths.iter().map(|t| t.obj_id).collect();
    let text = std::fs::read_to_string(results).map_err(io(results))?;
    let name = results.display();
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
            Err(reason) if skip_malformed => {
                malformed.push(format!("{name} line {number}: {reason}"))
            }
            Err(reason) => {
                return Err(FormatError::Invalid(format!(
                    "{name} line {number}: {reason} (pass --skip-malformed to count and skip such lines)"
                )));
            }
        }
    }
    let valid = estimates.len();
    let mut assigned = match_estimates(&truths, &frames, estimates, results)?;
    let rows = (0..truths.len())
        .map(|gt| Row {
            gt,
            matched: assigned.remove(&gt),
        })
        .collect();
    Ok(ResultsScore {
        truths,
        rows,
        valid,
        malformed,
    })
}

/// The greedy per-object matching of [`score_bop_results`]: truth index → its estimate.
fn match_estimates(
    truths: &[Truth],
    frames: &FrameTruths,
    estimates: Vec<Estimate>,
    results: &Path,
) -> Result<HashMap<usize, (Estimate, Scores)>> {
    let mut groups: BTreeMap<(i64, i32, u32), Vec<Estimate>> = BTreeMap::new();
    for e in estimates {
        groups
            .entry((e.scene_id, e.im_id, e.obj_id))
            .or_default()
            .push(e);
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
                let s = score(&truths[g], &e.pose).map_err(|source| FormatError::Geometry {
                    context: format!("{} line {}", results.display(), e.line),
                    source,
                })?;
                if best.as_ref().is_none_or(|(_, b)| s.cube_mssd < b.cube_mssd) {
                    best = Some((g, s));
                }
            }
            if let Some((g, s)) = best {
                assigned.insert(g, (e, s));
            }
        }
    }
    Ok(assigned)
}

impl ResultsScore {
    fn matched(&self) -> impl Iterator<Item = &(Estimate, Scores)> {
        self.rows.iter().filter_map(|r| r.matched.as_ref())
    }

    /// Per row, `error` of its match over the diameter; +∞ for a missed instance.
    fn over_diameter(&self, rows: &[&Row], error: fn(&Scores) -> f64) -> Vec<f64> {
        rows.iter()
            .map(|r| {
                r.matched.as_ref().map_or(f64::INFINITY, |(_, s)| {
                    error(s) / self.truths[r.gt].model.diameter()
                })
            })
            .collect()
    }

    /// BOP's AR_MSPD of `rows`: each MSPD against 5, 10, …, 50 pixels times its image's width
    /// over 640, a missed instance +∞.
    fn average_recall_mspd(&self, rows: &[&Row]) -> f64 {
        let at_width_640: Vec<f64> = rows
            .iter()
            .map(|r| {
                r.matched.as_ref().map_or(f64::INFINITY, |(_, s)| {
                    s.mspd * 640.0 / self.truths[r.gt].image_width as f64
                })
            })
            .collect();
        metrics::average_recall_at(&at_width_640, &metrics::AR_MSPD_THRESHOLDS_PX)
    }

    /// The share of `rows` whose `error` is below `k` diameters; NaN for no rows.
    fn recall(&self, rows: &[&Row], error: fn(&Scores) -> f64, k: f64) -> f64 {
        if rows.is_empty() {
            return f64::NAN;
        }
        let errors = self.over_diameter(rows, error);
        errors.iter().filter(|&&e| e < k).count() as f64 / rows.len() as f64
    }

    /// summary.json: counts of lines and instances, recalls and average recalls over every
    /// instance, and mean errors over the matched ones (null where there is none).
    pub fn summary(&self, results: &Path, dataset: &Path) -> Value {
        let n = self.rows.len();
        let matched: Vec<&(Estimate, Scores)> = self.matched().collect();
        let mean = |f: fn(&Scores) -> f64| {
            (!matched.is_empty())
                .then(|| matched.iter().map(|(_, s)| f(s)).sum::<f64>() / matched.len() as f64)
        };
        let all: Vec<&Row> = self.rows.iter().collect();
        json!({
            "results": results.display().to_string(),
            "dataset": dataset.display().to_string(),
            "result_lines": self.valid + self.malformed.len(),
            "results_valid": self.valid,
            "results_matched": matched.len(),
            "results_unmatched": self.valid - matched.len(),
            "malformed_lines": self.malformed.len(),
            "malformed": self.malformed,
            "instances": n,
            "instances_matched": matched.len(),
            "instances_missed": n - matched.len(),
            "recall_cube_mssd_0.05d": self.recall(&all, |s| s.cube_mssd, 0.05),
            "recall_cube_mssd_0.1d": self.recall(&all, |s| s.cube_mssd, 0.1),
            "recall_mssd_0.05d": self.recall(&all, |s| s.mssd, 0.05),
            "recall_mssd_0.1d": self.recall(&all, |s| s.mssd, 0.1),
            "ar_cube_mssd": metrics::average_recall(&self.over_diameter(&all, |s| s.cube_mssd)),
            "ar_mssd": metrics::average_recall(&self.over_diameter(&all, |s| s.mssd)),
            "ar_mspd": self.average_recall_mspd(&all),
            "mean_over_matched": {
                "cube_mssd_m": mean(|s| s.cube_mssd),
                "mssd_m": mean(|s| s.mssd),
                "add_s_m": mean(|s| s.add_s),
                "mspd_px": mean(|s| s.mspd),
                "paper_error_m2": mean(|s| s.paper_error),
                "paper_error_normalized": mean(|s| s.paper_error_normalized),
                "rotation_error_deg": mean(|s| s.rotation_error_deg),
                "translation_error_m": mean(|s| s.translation_error),
            },
        })
    }

    /// One line per obj_id in increasing order, then all objects together.
    pub fn per_object(&self) -> Vec<ObjectRecall> {
        let mut groups: BTreeMap<Option<u32>, Vec<&Row>> = BTreeMap::new();
        for r in &self.rows {
            groups
                .entry(Some(self.truths[r.gt].obj_id))
                .or_default()
                .push(r);
            groups.entry(None).or_default().push(r);
        }
        let mut order: Vec<Option<u32>> = groups.keys().copied().filter(Option::is_some).collect();
        order.push(None);
        order
            .into_iter()
            .map(|key| {
                let group = &groups[&key];
                let hits: Vec<&Scores> = group
                    .iter()
                    .filter_map(|r| r.matched.as_ref().map(|(_, s)| s))
                    .collect();
                let mean = |f: fn(&Scores) -> f64| {
                    (!hits.is_empty())
                        .then(|| hits.iter().map(|s| f(s)).sum::<f64>() / hits.len() as f64)
                };
                ObjectRecall {
                    obj_id: key,
                    instances: group.len(),
                    matched: hits.len(),
                    cube_mssd_005: self.recall(group, |s| s.cube_mssd, 0.05),
                    cube_mssd_01: self.recall(group, |s| s.cube_mssd, 0.1),
                    mssd_01: self.recall(group, |s| s.mssd, 0.1),
                    mean_mssd_mm: mean(|s| s.mssd * 1000.0),
                    mean_rotation_error_deg: mean(|s| s.rotation_error_deg),
                }
            })
            .collect()
    }

    /// eval_results.parquet (schema `EVAL_RESULTS`): one row per ground-truth instance.
    pub fn write_table(&self, path: &Path) -> Result<()> {
        let rows = &self.rows;
        let truth = |r: &Row| &self.truths[r.gt];
        // gt_id: the instance's rank in its frame (write_bop's order).
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
        let instance_column = |f: fn(&Instance) -> i32| {
            Arc::new(
                rows.iter()
                    .map(|r| f(&truth(r).instance))
                    .collect::<Int32Array>(),
            ) as ArrayRef
        };
        let columns: Vec<ArrayRef> = vec![
            Arc::new(
                rows.iter()
                    .map(|r| truth(r).instance.scene_id)
                    .collect::<Int64Array>(),
            ),
            instance_column(|i| i.frame_id),
            Arc::new(Int32Array::from(gt_ids)),
            instance_column(|i| i.object_id),
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
            metric(|s| s.mspd),
            metric(|s| s.paper_error),
            metric(|s| s.paper_error_normalized),
            metric(|s| s.rotation_error_deg),
            metric(|s| s.translation_error),
        ];
        boxpose_data::write_table(path, &boxpose_data::schema::EVAL_RESULTS, columns)?;
        Ok(())
    }
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
