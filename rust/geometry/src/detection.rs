//! Scores of an instance detector (the segmenter), as COCO defines them and pycocotools computes
//! them for one category (`tests/test_python_bindings.py` checks these against pycocotools):
//! overlaps, the greedy matching of detections to true instances, and average precision.

/// Intersection over union of two boolean masks of one image (row-major, equal length):
/// |a ∧ b| / |a ∨ b|, 0 when both are empty.
pub fn mask_iou(a: &[bool], b: &[bool]) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += (x && y) as usize;
        union += (x || y) as usize;
    }
    if union == 0 {
        0.0
    } else {
        inter as f64 / union as f64
    }
}

/// Intersection over union of two boxes `[x_min, y_min, x_max, y_max]` (max exclusive), 0 when
/// they do not overlap.
pub fn bbox_iou(a: &[i32; 4], b: &[i32; 4]) -> f64 {
    let w = (a[2].min(b[2]) - a[0].max(b[0])).max(0) as f64;
    let h = (a[3].min(b[3]) - a[1].max(b[1])).max(0) as f64;
    let area = |r: &[i32; 4]| ((r[2] - r[0]) * (r[3] - r[1])) as f64;
    let inter = w * h;
    if inter == 0.0 {
        0.0
    } else {
        inter / (area(a) + area(b) - inter)
    }
}

/// COCO's matching in one image: detections in order of decreasing score (ties: in the order
/// given) each take the not yet matched true instance they overlap most (ties: the later one, as
/// pycocotools), if that IoU is at least `threshold`. `ious[d][g]` is detection d's IoU with true instance g; returns, per detection,
/// the true instance it matched.
pub fn greedy_match(ious: &[Vec<f64>], scores: &[f32], threshold: f64) -> Vec<Option<usize>> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    let mut taken = vec![false; ious.first().map_or(0, Vec::len)];
    let mut matched = vec![None; scores.len()];
    for d in order {
        let best = ious[d]
            .iter()
            .enumerate()
            .filter(|(g, iou)| !taken[*g] && **iou >= threshold)
            .max_by(|a, b| a.1.total_cmp(b.1));
        if let Some((g, _)) = best {
            taken[g] = true;
            matched[d] = Some(g);
        }
    }
    matched
}

/// One image's detections for [`average_precision`]: each detection's score and its IoU with
/// each of the image's `true_count` true instances (`ious[d][g]`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImageDetections {
    pub scores: Vec<f32>,
    pub ious: Vec<Vec<f64>>,
    pub true_count: usize,
}

/// Detections per image that COCO's AP counts (its `maxDets`): the best-scoring ones.
pub const MAX_DETECTIONS_PER_IMAGE: usize = 100;

/// COCO's average precision at one IoU threshold over images: each image's best
/// [`MAX_DETECTIONS_PER_IMAGE`] detections matched by [`greedy_match`]; all of them ranked by
/// score (ties: image order, then detection order); precision made non-increasing in recall and
/// read at the 101 recall points 0, 0.01, …, 1 (0 where the recall is never reached), then
/// averaged. NaN without true instances.
pub fn average_precision(images: &[ImageDetections], threshold: f64) -> f64 {
    let true_count: usize = images.iter().map(|i| i.true_count).sum();
    if true_count == 0 {
        return f64::NAN;
    }
    let mut ranked: Vec<(f32, bool)> = Vec::new();
    for image in images {
        let mut best: Vec<usize> = (0..image.scores.len()).collect();
        best.sort_by(|&a, &b| image.scores[b].total_cmp(&image.scores[a]));
        best.truncate(MAX_DETECTIONS_PER_IMAGE);
        let scores: Vec<f32> = best.iter().map(|&d| image.scores[d]).collect();
        let ious: Vec<Vec<f64>> = best.iter().map(|&d| image.ious[d].clone()).collect();
        let matched = greedy_match(&ious, &scores, threshold);
        ranked.extend(scores.into_iter().zip(matched.iter().map(Option::is_some)));
    }
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (mut tp, mut fp) = (0usize, 0usize);
    let mut curve: Vec<(f64, f64)> = Vec::with_capacity(ranked.len());
    for (_, hit) in ranked {
        if hit {
            tp += 1
        } else {
            fp += 1
        }
        curve.push((tp as f64 / true_count as f64, tp as f64 / (tp + fp) as f64));
    }
    // The precision envelope: the best precision at this recall or any higher one.
    for i in (0..curve.len().saturating_sub(1)).rev() {
        curve[i].1 = curve[i].1.max(curve[i + 1].1);
    }
    (0..=100)
        .map(|r| {
            // As numpy's linspace(0, 1, 101) makes them, which decides ties with a recall of
            // exactly r/100.
            let recall = r as f64 * 0.01;
            curve
                .iter()
                .find(|(rec, _)| *rec >= recall)
                .map_or(0.0, |(_, precision)| *precision)
        })
        .sum::<f64>()
        / 101.0
}

/// COCO's AP: [`average_precision`] averaged over the IoU thresholds 0.50, 0.55, …, 0.95 (as
/// numpy's linspace(0.5, 0.95, 10) makes them, so that an IoU on a threshold counts the same).
pub fn coco_average_precision(images: &[ImageDetections]) -> f64 {
    let step = (0.95 - 0.5) / 9.0;
    (0..10)
        .map(|k| average_precision(images, 0.5 + k as f64 * step))
        .sum::<f64>()
        / 10.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matching_takes_the_best_free_instance_in_score_order() {
        // Detection 1 scores higher and takes instance 0; detection 0 then gets instance 1.
        let ious = vec![vec![0.9, 0.6], vec![0.8, 0.1]];
        assert_eq!(greedy_match(&ious, &[0.5, 0.9], 0.5), [Some(1), Some(0)]);
        assert_eq!(greedy_match(&ious, &[0.5, 0.9], 0.7), [None, Some(0)]);
    }

    #[test]
    fn average_precision_of_known_rankings() {
        let image = |scores: Vec<f32>, ious: Vec<Vec<f64>>, true_count| ImageDetections {
            scores,
            ious,
            true_count,
        };
        // Every instance found, no false positive: AP 1.
        let perfect = [image(
            vec![0.9, 0.8],
            vec![vec![1.0, 0.0], vec![0.0, 1.0]],
            2,
        )];
        assert_eq!(average_precision(&perfect, 0.5), 1.0);
        // A false positive ranked first, then one hit of two instances: precision 1/2 up to
        // recall 1/2, nothing beyond → 51 of 101 recall points at 0.5.
        let half = [image(
            vec![0.9, 0.8],
            vec![vec![0.0, 0.0], vec![0.7, 0.0]],
            2,
        )];
        assert!((average_precision(&half, 0.5) - 0.5 * 51.0 / 101.0).abs() < 1e-12);
        // The hit does not reach a 0.75 threshold.
        assert_eq!(average_precision(&half, 0.75), 0.0);
        assert!(average_precision(&[image(vec![0.5], vec![vec![]], 0)], 0.5).is_nan());
    }
}
