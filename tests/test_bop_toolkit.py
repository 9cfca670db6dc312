"""bop_toolkit's own evaluation scripts on a `boxpose export bop` folder: the pinned copy in
third_party/bop_toolkit, the dataset registered by scripts/register_bop_toolkit.py from the
export's bop_toolkit_dataset_params.txt, and a results CSV of perturbed poses. Its MSSD of every
estimate and its recall at each of BOP's thresholds equal `boxpose eval-results bop`'s."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import bpy  # noqa: F401  (installed by `make setup`: a missing bpy fails, never skips)
import numpy as np
import pandas as pd
import pytest

from boxpose_io.rotations import quat_to_matrix
from conftest import render_synthetic_dataset, run_boxpose

REPO = Path(__file__).resolve().parents[1]
BOP_TOOLKIT = REPO / "third_party" / "bop_toolkit"
# a dataset name without "_" or "-": bop_toolkit reads it from METHOD_DATASET-SPLIT.csv
NAME = "boxposetest"
RESULTS = f"perturbed_{NAME}-test.csv"
PREDICTED = f"predict_{NAME}-test.csv"
# BOP's AR_MSSD thresholds, × the object's diameter
THRESHOLDS = [round(0.05 * k, 2) for k in range(1, 11)]


@pytest.fixture(scope="module")
def exported(tmp_path_factory, boxpose_bin) -> dict:
    """The tiny dataset, its export under a BOP_PATH folder, and a bop_toolkit copy with the
    export registered."""
    root = tmp_path_factory.mktemp("bop_toolkit")
    dataset = render_synthetic_dataset(root / "ds", 64, 48, shared_size_in_scene_0=True)
    datasets = root / "datasets"
    run_boxpose(boxpose_bin, "export", "bop", dataset, datasets / NAME)
    toolkit = root / "bop_toolkit"
    shutil.copytree(BOP_TOOLKIT, toolkit)
    script = REPO / "scripts" / "register_bop_toolkit.py"
    register = [sys.executable, script, toolkit, datasets / NAME]
    r = subprocess.run(register, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return dict(root=root, dataset=dataset, datasets=datasets, toolkit=toolkit, register=register)


def perturbed_results(export: Path) -> str:
    """A results CSV: every annotated box's true pose turned about a random axis by 0–20° and
    shifted by up to 15 mm (errors spread over BOP's thresholds), scored in random order."""
    rng = np.random.default_rng(7)
    lines = ["scene_id,im_id,obj_id,score,R,t,time"]
    for scene in sorted((export / "test").iterdir()):
        for im_id, boxes in json.loads((scene / "scene_gt.json").read_text()).items():
            for g in boxes:
                axis = rng.normal(size=3)
                axis /= np.linalg.norm(axis)
                angle = np.radians(rng.uniform(0.0, 20.0))
                x, y, z = axis
                cross = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
                turn = np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross
                r = np.array(g["cam_R_m2c"]).reshape(3, 3) @ turn
                t = np.array(g["cam_t_m2c"]) + rng.uniform(-15.0, 15.0, 3)
                values = " ".join(map(repr, r.ravel().tolist())), " ".join(map(repr, t.tolist()))
                score = rng.uniform(0.1, 1.0)
                lines.append(
                    f"{int(scene.name)},{im_id},{g['obj_id']},{score},{values[0]},{values[1]},-1"
                )
    return "\n".join(lines) + "\n"


def bop_toolkit(exported: dict, script: str, *args) -> None:
    env = dict(
        os.environ,
        PYTHONPATH=str(exported["toolkit"]),
        BOP_PATH=str(exported["datasets"]),
        BOP_RESULTS_PATH=str(exported["root"] / "results"),
        BOP_EVAL_PATH=str(exported["root"] / "eval"),
        BOP_NUM_WORKERS="1",
    )
    r = subprocess.run(
        [sys.executable, exported["toolkit"] / "scripts" / script, *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=exported["toolkit"],
    )
    assert r.returncode == 0, r.stderr[-3000:]


def bop_toolkit_errors(exported: dict, error_type: str, results: str) -> tuple[str, dict]:
    """eval_calc_errors.py as BOP'19 runs it (every estimate up to the number of boxes per object
    and image, the targets file's boxes: visib_fract >= 0.1): its folder and, per box, its error.
    An estimate has an error against every box of its obj_id (scene 0's two boxes share one);
    each box's is its nearest estimate's, the one both matchings pair it with (the moves are far
    smaller than the boxes' spacing)."""
    bop_toolkit(
        exported,
        "eval_calc_errors.py",
        f"--error_type={error_type}",
        "--n_top=-1",
        f"--result_filenames={results}",
    )
    errors_dir = f"{results[:-4]}/error={error_type}_ntop=-1"
    errors = {}
    for path in (exported["root"] / "eval" / errors_dir).glob("errors_*.json"):
        for e in json.loads(path.read_text()):
            for gt_id, (error,) in e["errors"].items():
                key = (e["scene_id"], e["im_id"], int(gt_id))
                errors[key] = min(error, errors.get(key, np.inf))
    return errors_dir, errors


def bop_toolkit_recall(exported: dict, errors_dir: str, error_type: str, threshold: float) -> float:
    # one threshold a call: a list is one multi-part threshold (rete)
    bop_toolkit(
        exported,
        "eval_calc_scores.py",
        f"--error_dir_paths={errors_dir}",
        f"--correct_th_{error_type}={threshold}",
    )
    scores = (
        exported["root"] / "eval" / errors_dir / f"scores_th={threshold:.3f}_min-visib=-1.000.json"
    )
    return json.loads(scores.read_text())["recall"]


def test_bop_toolkit_scores_an_export_as_eval_results_does(exported, boxpose_bin):
    export = exported["datasets"] / NAME
    results = exported["root"] / "results"
    results.mkdir()
    (results / RESULTS).write_text(perturbed_results(export))
    ours = exported["root"] / "eval_results"
    run_boxpose(
        boxpose_bin, "eval-results", "bop", results / RESULTS, exported["dataset"], "--out", ours
    )
    table = pd.read_parquet(ours / "eval_results.parquet")
    summary = json.loads((ours / "summary.json").read_text())
    targets = table[table.visib_fract >= 0.1].set_index(["scene_id", "im_id", "gt_id"])
    # every box of this dataset is a target, so the summary's average recalls are over the same
    # boxes as bop_toolkit's
    assert len(targets) == len(table) >= 8
    width = json.loads((export / "camera.json").read_text())["width"]

    # MSSD, bop_toolkit in mm. The export's models round the box size to 0.1 mm, which moves a
    # corner by at most 0.05·√3 mm and its error under a turn by θ ≤ 20° by at most 2·sin(θ/2)
    # times that (< 0.04 mm). MSPD in pixels: that rounding moves a corner's image by < 0.02 px.
    for error_type, column, scale, tolerance, thresholds, normalizer, average in (
        ("mssd", "mssd_m", 1000.0, 0.04, THRESHOLDS, targets.diameter_m, "ar_mssd"),
        ("mspd", "mspd_px", 1.0, 0.02, [5.0 * k for k in range(1, 11)], width / 640, "ar_mspd"),
    ):
        errors_dir, theirs = bop_toolkit_errors(exported, error_type, RESULTS)
        assert set(theirs) == set(targets.index), error_type
        for key, error in theirs.items():
            assert error == pytest.approx(scale * targets.loc[key, column], abs=tolerance), key
        # the recall at each threshold (× the diameter for MSSD, × width/640 for MSPD): spread,
        # and the same
        recalls = []
        for th in thresholds:
            recall = bop_toolkit_recall(exported, errors_dir, error_type, th)
            ours_at = (targets[column] < th * normalizer).mean()
            assert recall == pytest.approx(ours_at, abs=1e-12), (error_type, th)
            recalls.append(recall)
        assert recalls[0] < recalls[-1] and recalls == sorted(recalls), (error_type, recalls)
        assert summary[average] == pytest.approx(np.mean(recalls), abs=1e-12), error_type


def predicted_results(exported: dict, boxpose_bin) -> str:
    """A results CSV of `boxpose predict` (the shipped keypoint network on ground-truth crops, the
    size fit) on scene 1's frames, whose boxes all differ in size: each box with its own obj_id
    (gt_id is the object id: every frame lists every box), the fit's confidence as the score."""
    export = exported["datasets"] / NAME
    lines = ["scene_id,im_id,obj_id,score,R,t,time"]
    scene_gt = json.loads((export / "test" / "000001" / "scene_gt.json").read_text())
    for im_id, boxes in scene_gt.items():
        out = exported["root"] / "predict" / im_id
        run_boxpose(
            boxpose_bin,
            "predict",
            exported["dataset"],
            "--scene",
            1,
            "--frame",
            im_id,
            "--out",
            out,
        )
        for b in json.loads((out / "predictions.json").read_text())["boxes"]:
            fit = b["fit"]
            if fit is None:
                continue
            r = quat_to_matrix(fit["pose_quat_wxyz"])
            t = 1000.0 * np.array(fit["pose_translation_m"])
            values = " ".join(map(repr, r.ravel().tolist())), " ".join(map(repr, t.tolist()))
            obj_id, score = boxes[b["object_id"]]["obj_id"], fit["confidence"]["confidence"]
            lines.append(f"1,{im_id},{obj_id},{score},{values[0]},{values[1]},-1")
    assert len(lines) > 4
    return "\n".join(lines) + "\n"


def test_bop_toolkit_scores_predict_s_poses_as_eval_results_does(exported, boxpose_bin):
    results = exported["root"] / "results"
    results.mkdir(exist_ok=True)
    (results / PREDICTED).write_text(predicted_results(exported, boxpose_bin))
    ours = exported["root"] / "eval_results_predicted"
    run_boxpose(
        boxpose_bin, "eval-results", "bop", results / PREDICTED, exported["dataset"], "--out", ours
    )
    table = pd.read_parquet(ours / "eval_results.parquet").set_index(["scene_id", "im_id", "gt_id"])
    errors_dir, theirs = bop_toolkit_errors(exported, "mssd", PREDICTED)
    # scene 0 has no estimate: a miss in both
    assert {key[0] for key in theirs} == {1} and len(theirs) == table.matched.sum() >= 4
    for key, error in theirs.items():
        assert error == pytest.approx(1000.0 * table.loc[key, "mssd_m"], abs=0.04), key
    for th in (0.1, 0.3, 0.5):
        recall = bop_toolkit_recall(exported, errors_dir, "mssd", th)
        assert recall == pytest.approx((table.mssd_m < th * table.diameter_m).mean(), abs=1e-12)


def test_a_dataset_is_registered_once(exported):
    r = subprocess.run(exported["register"], capture_output=True, text=True)
    assert r.returncode == 1
    assert f'the dataset "{NAME}" is already registered' in r.stderr
