"""The segmenter's scores against pycocotools, the reference implementation of COCO's metrics:
mask IoU and average precision at every COCO threshold (`boxpose_geometry::detection`, which
`boxpose eval` and the segmenter's validation use), on random images with missed boxes, false
positives, loose masks and tied scores."""

import contextlib
import io

import numpy as np
import pytest
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

import boxpose

HEIGHT, WIDTH = 24, 32


def random_box_mask(rng) -> np.ndarray:
    mask = np.zeros((HEIGHT, WIDTH), bool)
    x0, y0 = rng.integers(0, WIDTH - 4), rng.integers(0, HEIGHT - 4)
    mask[y0 : y0 + rng.integers(3, 12), x0 : x0 + rng.integers(3, 14)] = True
    return mask


def random_images(seed: int, count: int):
    """Per image: true masks, detected masks and their scores (float32, often tied)."""
    rng = np.random.default_rng(seed)
    images = []
    for _ in range(count):
        truths = [random_box_mask(rng) for _ in range(rng.integers(0, 5))]
        detections = []
        for truth in truths:
            if rng.random() < 0.8:  # found, more or less tightly: shifted, edge pixels flipped
                found = np.roll(truth, rng.integers(-1, 2, 2), axis=(0, 1))
                ys, xs = np.nonzero(truth)
                near = np.zeros_like(truth)
                near[max(ys.min() - 1, 0) : ys.max() + 2, max(xs.min() - 1, 0) : xs.max() + 2] = (
                    True
                )
                found ^= near & (rng.random(found.shape) < rng.uniform(0, 0.3))
                detections.append(found)
        detections += [random_box_mask(rng) for _ in range(rng.integers(0, 3))]
        scores = np.round(rng.random(len(detections)), 1).astype(np.float32)
        images.append((truths, detections, scores))
    return images


def coco_precision(images) -> np.ndarray:
    """pycocotools' precision table, (thresholds, recall points), for one category, all areas,
    100 detections per image."""

    def rle(mask):
        return mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))

    truth_annotations, results = [], []
    for image_id, (truths, detections, scores) in enumerate(images):
        for truth in truths:
            encoded = rle(truth)
            truth_annotations.append(
                dict(
                    id=len(truth_annotations) + 1,
                    image_id=image_id,
                    category_id=1,
                    segmentation=encoded,
                    area=float(mask_utils.area(encoded)),
                    bbox=mask_utils.toBbox(encoded).tolist(),
                    iscrowd=0,
                )
            )
        for detection, score in zip(detections, scores, strict=True):
            results.append(
                dict(
                    image_id=image_id,
                    category_id=1,
                    segmentation=rle(detection),
                    score=float(score),
                )
            )
    with contextlib.redirect_stdout(io.StringIO()):
        truth = COCO()
        truth.dataset = dict(
            info={},
            images=[dict(id=i, height=HEIGHT, width=WIDTH) for i in range(len(images))],
            annotations=truth_annotations,
            categories=[dict(id=1, name="box")],
        )
        truth.createIndex()
        evaluation = COCOeval(truth, truth.loadRes(results), "segm")
        evaluation.evaluate()
        evaluation.accumulate()
    return evaluation.eval["precision"][:, :, 0, 0, 2], evaluation.params.iouThrs


@pytest.mark.parametrize("seed", range(8))
def test_average_precision_agrees_with_pycocotools(seed):
    images = random_images(seed, count=6)
    assert any(len(d) for _, d, _ in images) and any(len(t) for t, _, _ in images)
    per_image = []
    for truths, detections, scores in images:
        ious = np.array(
            [[boxpose.mask_iou(d, t) for t in truths] for d in detections], dtype=np.float64
        ).reshape(len(detections), len(truths))
        per_image.append((scores, ious))
    precision, thresholds = coco_precision(images)
    for k, threshold in enumerate(thresholds):
        expected = precision[k].mean()
        assert boxpose.average_precision(per_image, float(threshold)) == pytest.approx(
            expected, abs=1e-12
        ), f"IoU threshold {threshold}"


def test_mask_iou_agrees_with_pycocotools():
    rng = np.random.default_rng(3)
    for _ in range(50):
        a, b = random_box_mask(rng), random_box_mask(rng)
        encoded = [mask_utils.encode(np.asfortranarray(m.astype(np.uint8))) for m in (a, b)]
        expected = mask_utils.iou([encoded[0]], [encoded[1]], [0])[0, 0]
        assert boxpose.mask_iou(a, b) == expected


def test_average_precision_refuses_inconsistent_input():
    with pytest.raises(ValueError, match="2 scores for 1 rows"):
        boxpose.average_precision([(np.ones(2, np.float32), np.zeros((1, 1)))], 0.5)
    with pytest.raises(ValueError, match="not in"):
        boxpose.average_precision([], 1.5)
    assert np.isnan(boxpose.average_precision([(np.ones(1, np.float32), np.zeros((1, 0)))], 0.5))
