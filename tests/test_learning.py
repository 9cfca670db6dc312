"""`boxpose train`, `predict` and `eval` on a real tiny dataset (Drake scenes, Blender 64²
renders): a tiny network for a few steps, interrupted and resumed; then its predictions and
evaluation read back with pandas. The numbers of a 4-step network mean nothing; the plumbing and
files are tested."""

import io
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from PIL import Image

import boxpose_io
from conftest import REPO, peak_rss_mb, render_synthetic_dataset, run_boxpose


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("learn") / "tiny"
    r = subprocess.run(
        [
            sys.executable,
            REPO / "scripts" / "make_scenes.py",
            "--recipe",
            "tiny",
            "--dataset",
            root,
            "--num-scenes",
            "4",
            "--no-inspect",
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr
    return root


@pytest.fixture(scope="module")
def trained(tiny_dataset, boxpose_bin, tmp_path_factory):
    """A tiny model trained for 4 steps, interrupted after 2 and resumed."""
    run = tmp_path_factory.mktemp("run") / "tiny-run"
    args = [
        "train",
        "--config",
        REPO / "configs" / "tiny.toml",
        "--dataset",
        tiny_dataset,
        "--out",
        run,
    ]
    first = run_boxpose(boxpose_bin, *args, "--stop-after", "2")
    second = run_boxpose(boxpose_bin, *args)
    return run, first, second


def test_an_interrupted_run_resumes_from_its_checkpoint(trained):
    run, first, second = trained
    assert "stopped early" in first.stdout
    assert not (run / "model").exists() or "resumed" in second.stdout
    assert "resumed from the checkpoint at step 2" in second.stdout
    history = pd.read_csv(run / "history.csv")
    assert list(history.step) == [2, 4]  # validate_every = 2: one row per checkpoint, none repeated
    assert np.isfinite(history.train_loss).all() and (history.train_loss > 0).all()
    assert history.corner_recall.between(0, 1).all()
    assert (run / "model" / "network.toml").is_file() and (run / "model" / "model.bpk").is_file()
    assert not list(run.glob("*.tmp")) and not list(run.glob("*.old"))


def test_training_says_how_each_dataset_divides(trained, segmenter, tiny_dataset):
    """The headline's totals, then a line per dataset with its share: here the one dataset holds
    all of them (tiny's scene 0 is held out, scenes 1–3 are trained on)."""
    for result, unit in ((trained[1], "instances"), (segmenter[1], "frames")):
        totals = re.search(rf"on (\d+) training / (\d+) held-out {unit}", result.stdout)
        share = re.search(
            rf"^  {re.escape(str(tiny_dataset))}: (\d+) training / (\d+) held-out {unit}$",
            result.stdout,
            re.MULTILINE,
        )
        assert totals and share, result.stdout
        assert share.groups() == totals.groups()
        assert all(int(n) > 0 for n in share.groups()), share.group(0)


def test_repeat_weighs_each_dataset_in_the_mix(tiny_dataset, boxpose_bin, tmp_path):
    """`--repeat 3,1` trains on three copies of the first dataset's training scenes per epoch
    beside one of the second's (here the same folder twice); held-out scenes are never repeated,
    and a count per dataset is required."""
    args = ["train", "--config", REPO / "configs" / "tiny.toml"]
    args += ["--dataset", tiny_dataset, "--dataset", tiny_dataset]
    r = run_boxpose(boxpose_bin, *args, "--repeat", "3,1", "--steps", 1, "--out", tmp_path / "run")
    totals = re.search(r"on (\d+) training / (\d+) held-out instances", r.stdout)
    shares = re.findall(
        rf"^  {re.escape(str(tiny_dataset))}: (\d+) training( \(×3 per epoch\))? / (\d+) held-out",
        r.stdout,
        re.MULTILINE,
    )
    assert totals and len(shares) == 2, r.stdout
    (n, thrice, held_out), (n2, once, held_out2) = shares
    assert n == n2 and held_out == held_out2 and thrice and not once, shares
    assert int(totals.group(1)) == 4 * int(n) and int(totals.group(2)) == 2 * int(held_out)
    bad = run_boxpose(boxpose_bin, *args, "--repeat", 2, "--out", tmp_path / "bad", check=False)
    assert bad.returncode != 0
    assert "[data] repeat has 1 entries for 2 datasets" in bad.stderr, bad.stderr
    assert not (tmp_path / "bad").exists()


def test_the_same_seed_trains_the_same_network_with_or_without_an_interruption(
    trained, tiny_dataset, boxpose_bin, tmp_path
):
    run, _, _ = trained
    again = tmp_path / "again"  # the same config, in one go
    run_boxpose(
        boxpose_bin,
        "train",
        "--config",
        REPO / "configs" / "tiny.toml",
        "--dataset",
        tiny_dataset,
        "--out",
        again,
    )
    assert (
        pd.read_csv(again / "history.csv").train_loss.tolist()
        == pd.read_csv(run / "history.csv").train_loss.tolist()
    )
    # the weight files differ only in burn's random parameter ids: compare what the models predict
    scene = int(pd.read_parquet(tiny_dataset / "frames").scene_id.iloc[0])
    outputs = []
    for model in (run / "model", again / "model"):
        out = tmp_path / f"{model.parent.name}-predictions"
        run_boxpose(
            boxpose_bin, "predict", tiny_dataset, "--scene", scene, "--model", model, "--out", out
        )
        outputs.append(json.loads((out / "predictions.json").read_text()))
    assert outputs[0] == outputs[1]


def test_a_changed_config_does_not_silently_resume(trained, tiny_dataset, boxpose_bin, tmp_path):
    run, _, _ = trained
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    r = run_boxpose(
        boxpose_bin,
        "train",
        "--config",
        REPO / "configs" / "tiny.toml",
        "--dataset",
        tiny_dataset,
        "--out",
        copy,
        "--learning-rate",
        "0.5",
        check=False,
    )
    assert r.returncode != 0
    assert "another configuration" in r.stderr and "--restart" in r.stderr


def test_a_corrupt_checkpoint_is_one_clear_error(trained, tiny_dataset, boxpose_bin, tmp_path):
    run, _, _ = trained
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    (copy / "checkpoint" / "model.bpk").write_bytes(b"not a burnpack")
    r = run_boxpose(
        boxpose_bin,
        "train",
        "--config",
        REPO / "configs" / "tiny.toml",
        "--dataset",
        tiny_dataset,
        "--out",
        copy,
        check=False,
    )
    assert r.returncode != 0
    assert "checkpoint/model.bpk" in r.stderr and "--restart" in r.stderr
    assert "panicked" not in r.stderr


def test_predict_writes_poses_peaks_and_an_overlay(trained, tiny_dataset, boxpose_bin, tmp_path):
    run, _, _ = trained
    instances = pd.read_parquet(tiny_dataset / "instances")
    scene = int(instances.scene_id.iloc[0])
    out = tmp_path / "predict"
    r = run_boxpose(
        boxpose_bin,
        "predict",
        tiny_dataset,
        "--scene",
        scene,
        "--frame",
        0,
        "--model",
        run / "model",
        "--out",
        out,
    )
    visible = instances[
        (instances.scene_id == scene) & (instances.frame_id == 0) & (instances.visible_pixels > 0)
    ]
    table = pd.read_parquet(out / "predictions.parquet")
    assert pq.read_schema(out / "predictions.parquet").metadata[b"boxpose.table"] == b"predictions"
    assert sorted(table.object_id) == sorted(visible.object_id)
    for row in table.itertuples():
        assert (
            len(row.peaks_camera_m) == 3 * len(row.peak_scores) and 1 <= len(row.peak_scores) <= 8
        )
        assert list(row.peak_scores) == sorted(row.peak_scores, reverse=True)
        if row.fit_error is None:
            assert len(row.corners_camera_m) == 24 and np.isfinite(row.corners_camera_m).all()
            assert np.isclose(np.linalg.norm(row.pose_quat_wxyz), 1.0)
    boxes = json.loads((out / "predictions.json").read_text())["boxes"]
    assert len(boxes) == len(table)
    overlay = np.asarray(Image.open(out / "overlay.png"))
    assert overlay.shape == (64, 64, 3)
    assert "overlay" in r.stdout


def test_predict_from_files_with_given_boxes(trained, tiny_dataset, boxpose_bin, tmp_path):
    run, _, _ = trained

    frames = pd.read_parquet(tiny_dataset / "frames")
    instances = pd.read_parquet(tiny_dataset / "instances")
    f = frames.iloc[0]
    (tmp_path / "rgb.png").write_bytes(f.rgb_png)
    depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(f.height, f.width)
    Image.fromarray((depth * 1000).round().astype(np.uint16)).save(tmp_path / "depth.png")
    inst = instances[
        (instances.scene_id == f.scene_id)
        & (instances.frame_id == f.frame_id)
        & (instances.visible_pixels > 0)
    ].iloc[0]
    bbox = ",".join(str(int(v)) for v in inst.visible_bbox_px)
    out = tmp_path / "out"
    run_boxpose(
        boxpose_bin,
        "predict",
        "--rgb",
        tmp_path / "rgb.png",
        "--depth",
        tmp_path / "depth.png",
        "--intrinsics",
        f"{f.fx},{f.fy},{f.cx},{f.cy}",
        "--bbox",
        bbox,
        "--model",
        run / "model",
        "--out",
        out,
    )
    table = pd.read_parquet(out / "predictions.parquet")
    assert len(table) == 1 and table.object_id.isna().all()
    # without ground truth the reference depth comes from the whole box: close to the box's own
    assert abs(table.reference_depth_m.iloc[0] - inst.camera_box_translation_m[2]) < 0.3
    r = run_boxpose(
        boxpose_bin,
        "predict",
        "--rgb",
        tmp_path / "rgb.png",
        "--depth",
        tmp_path / "rgb.png",
        "--intrinsics",
        "1,1,1,1",
        "--bbox",
        bbox,
        "--model",
        run / "model",
        "--out",
        out,
        check=False,
    )
    assert r.returncode != 0 and "rgb.png" in r.stderr and "16-bit" in r.stderr


def test_eval_writes_metrics_a_summary_and_the_error_histogram(
    trained, tiny_dataset, boxpose_bin, tmp_path
):
    run, _, _ = trained
    out = tmp_path / "eval"
    r = run_boxpose(
        boxpose_bin,
        "eval",
        tiny_dataset,
        "--model",
        run / "model",
        "--out",
        out,
        "--min-visible-fraction",
        "0.05",
    )
    # a result table of the contract: its schema version and name in the Parquet metadata
    metadata = pq.read_schema(out / "eval.parquet").metadata
    assert metadata[b"boxpose.table"] == b"eval" and b"boxpose.schema_version" in metadata
    rows = pd.read_parquet(out / "eval.parquet")
    # the four fits, and the former robust and size fits beside them for comparison
    methods = {
        "paper_exact",
        "fast_exact",
        "robust",
        "size_and_pose",
        "robust_fixed",
        "size_and_pose_ls",
    }
    assert set(rows.method) == methods
    per_instance = rows.groupby(["scene_id", "frame_id", "object_id"])
    assert (per_instance.size() == len(methods)).all()
    assert rows.corners_found.between(0, 8).all() and (rows.heatmap_mse > 0).all()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["instances"] == per_instance.ngroups
    assert 0 <= summary["corner_recall"] <= 1
    hist = Image.open(out / "paper_error_hist.png")
    assert hist.size == (900, 540)
    assert "corner recall" in r.stdout and "robust" in r.stdout


def test_eval_refine_depth_lays_the_known_size_fits_on_the_depth_image(
    tiny_dataset, boxpose_bin, tmp_path
):
    """`eval --refine-depth` (as `search --refine-depth`): the shipped network's known-size fits
    move onto the rendered depth of the box's faces and get closer to the truth; the size fits,
    which it leaves alone, stay as they were."""
    rows = {}
    for name, flags in [("plain", []), ("refined", ["--refine-depth"])]:
        out = tmp_path / f"run-{name}"
        args = ["--out", out, "--min-visible-fraction", "0.05", *flags]
        run_boxpose(boxpose_bin, "eval", tiny_dataset, *args)
        rows[name] = pd.read_parquet(out / "eval.parquet")
    keys = ["scene_id", "frame_id", "object_id", "method"]
    paired = rows["plain"].merge(rows["refined"], on=keys, suffixes=("", "_refined"))
    assert len(paired) == len(rows["plain"]) > 0
    moved = paired.translation_error_m != paired.translation_error_m_refined
    size_fits = paired.method.isin(["size_and_pose", "size_and_pose_ls"])
    assert not moved[size_fits].any()
    robust = paired[paired.method == "robust"]
    assert moved[paired.method == "robust"].mean() > 0.5
    assert robust.translation_error_m_refined.median() < robust.translation_error_m.median()
    assert robust.rotation_error_deg_refined.median() < robust.rotation_error_deg.median()


def test_eval_held_out_keeps_only_the_held_out_scenes(trained, tiny_dataset, boxpose_bin, tmp_path):
    everything = tmp_path / "all"
    held_out = tmp_path / "held_out"
    run_boxpose(
        boxpose_bin,
        "eval",
        tiny_dataset,
        "--model",
        trained[0] / "model",
        "--out",
        everything,
        "--min-visible-fraction",
        "0.05",
    )
    run_boxpose(
        boxpose_bin,
        "eval",
        tiny_dataset,
        "--model",
        trained[0] / "model",
        "--out",
        held_out,
        "--min-visible-fraction",
        "0.05",
        "--held-out",
        "2",
    )
    all_scenes = set(pd.read_parquet(everything / "eval.parquet").scene_id)
    held_out_scenes = set(pd.read_parquet(held_out / "eval.parquet").scene_id)
    assert (
        held_out_scenes == {s for s in all_scenes if s % 2 == 0} and held_out_scenes != all_scenes
    )


def test_a_missing_model_is_one_clear_error(tiny_dataset, boxpose_bin, tmp_path):
    r = run_boxpose(boxpose_bin, "eval", tiny_dataset, "--model", tmp_path / "nowhere", check=False)
    assert r.returncode != 0 and "nowhere/network.toml" in r.stderr and "panicked" not in r.stderr


@pytest.fixture(scope="module")
def segmenter(tiny_dataset, boxpose_bin, tmp_path_factory):
    run = tmp_path_factory.mktemp("seg") / "seg-run"
    r = run_boxpose(
        boxpose_bin,
        "train-segmenter",
        "--config",
        REPO / "configs" / "segmenter-tiny.toml",
        "--dataset",
        tiny_dataset,
        "--out",
        run,
    )
    return run, r


def test_the_segmenter_trains_and_reports_average_precision(segmenter):
    run, r = segmenter
    history = pd.read_csv(run / "history.csv")
    assert list(history.step) == [2, 4]
    for column in ("mask_ap50", "mask_ap", "bbox_ap50", "bbox_ap"):
        assert history[column].between(0, 1).all(), column
    assert (
        history.mask_ap <= history.mask_ap50 + 1e-12
    ).all()  # AP over 0.50:0.95 never beats AP50
    assert (run / "model" / "segmenter.toml").is_file() and (run / "model" / "model.bpk").is_file()


def test_eval_on_predicted_crops_counts_missed_boxes_as_failures(
    trained, segmenter, tiny_dataset, boxpose_bin, tmp_path
):
    out = tmp_path / "eval"
    r = run_boxpose(
        boxpose_bin,
        "eval",
        tiny_dataset,
        "--model",
        trained[0] / "model",
        "--crops",
        "predicted",
        "--segmenter",
        segmenter[0] / "model",
        "--out",
        out,
        "--min-visible-fraction",
        "0.05",
    )
    seg = json.loads((out / "segmentation.json").read_text())
    assert 0 <= seg["mask_ap50"] <= 1 and seg["true_instances"] > 0
    rows = pd.read_parquet(out / "eval.parquet")
    missed = rows[rows.fit_error == "not found by the segmenter"]
    assert missed.heatmap_mse.isna().all() and (missed.corners_found == 0).all()
    found = rows[rows.fit_error != "not found by the segmenter"]
    assert found.heatmap_mse.notna().all()
    assert "segmenter" in r.stdout and "mask AP" in r.stdout

    # A second evaluation into the same folder, on ground-truth crops, leaves no stale
    # segmenter scores beside its own results.
    run_boxpose(
        boxpose_bin,
        "eval",
        tiny_dataset,
        "--model",
        trained[0] / "model",
        "--out",
        out,
        "--min-visible-fraction",
        "0.05",
    )
    assert not (out / "segmentation.json").exists()
    assert (out / "summary.json").is_file() and not list(out.glob("*.tmp"))


def enlarged_copy(dataset, root, copies: int, scale: int):
    """`copies` copies of every scene of `dataset` (new scene ids), each image `scale` times
    larger (nearest neighbour; intrinsics and pixel coordinates scaled alike, so the tiny
    models still apply) and its depth perturbed in the last bits so that it does not compress.
    Returns the decoded size of its frames in MB."""
    rng = np.random.default_rng(0)
    tables = {name: pd.read_parquet(dataset / name) for name in boxpose_io.TABLES}
    frames = tables["frames"]
    big = []
    for f in frames.itertuples():
        w, h = f.width * scale, f.height * scale
        rgb = Image.open(io.BytesIO(f.rgb_png)).resize((w, h), Image.Resampling.NEAREST)
        mask = Image.open(io.BytesIO(f.instance_mask_png)).resize((w, h), Image.Resampling.NEAREST)
        depth = np.frombuffer(f.depth_m_f32le, "<f4").reshape(f.height, f.width)
        depth = depth.repeat(scale, 0).repeat(scale, 1)
        encoded = []
        for image in (rgb, mask):
            buffer = io.BytesIO()
            image.save(buffer, "PNG")
            encoded.append(buffer.getvalue())
        big.append(
            {
                "width": w,
                "height": h,
                "fx": f.fx * scale,
                "fy": f.fy * scale,
                "cx": (f.cx + 0.5) * scale - 0.5,
                "cy": (f.cy + 0.5) * scale - 0.5,
                "rgb_png": encoded[0],
                "instance_mask_png": encoded[1],
                "sensor_depth_m_f32le": None,
                "depth": depth,
            }
        )
    frames = frames.assign(**{k: [b[k] for b in big] for k in big[0] if k != "depth"})
    instances = tables["instances"].copy()
    instances["visible_bbox_px"] = [
        None if b is None else [v * scale for v in b] for b in instances.visible_bbox_px
    ]
    instances["visible_pixels"] *= scale * scale
    for column in ("corners_px", "label_keypoints_px"):
        instances[column] = [
            None if p is None else [(v + 0.5) * scale - 0.5 for v in p] for p in instances[column]
        ]
    scene_offset = int(tables["scenes"].scene_id.max()) + 1
    for name, table in list(tables.items()):
        parts = []
        for copy in range(copies):
            part = (instances if name == "instances" else table).copy()
            if name == "frames":
                part = frames.copy()
                part["depth_m_f32le"] = [
                    (b["depth"] * (1 + rng.uniform(-1e-5, 1e-5, b["depth"].shape)))
                    .astype("<f4")
                    .tobytes()
                    for b in big
                ]
            part["scene_id"] += copy * scene_offset
            parts.append(part)
        rows = [
            {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in row.items()}
            for row in pd.concat(parts).to_dict("records")
        ]
        path = boxpose_io.shard_path(root, name, 0, 1)
        boxpose_io.write_shard(path, boxpose_io.table_from_rows(name, rows))
    pixels = sum(b["width"] * b["height"] for b in big) * copies
    return pixels * (3 + 4 + 2) / 2**20


def test_training_and_evaluation_hold_a_bounded_part_of_a_large_dataset(
    trained, segmenter, tiny_dataset, boxpose_bin, tmp_path
):
    """Frames are read from their shards as needed: training keeps at most `frame_cache_mib`
    of decoded frames, and evaluation on the segmenter's crops one frame (it used to keep
    every frame's mask and every detection's, training every decoded frame)."""
    big = tmp_path / "big"
    decoded_mb = enlarged_copy(tiny_dataset, big, copies=48, scale=8)
    assert decoded_mb > 400
    config = tmp_path / "tiny.toml"
    config.write_text(
        (REPO / "configs" / "tiny.toml")
        .read_text()
        .replace("loader_threads = 1", "loader_threads = 1\nframe_cache_mib = 16")
    )
    train = peak_rss_mb(
        boxpose_bin, "train", "--config", config, "--dataset", big, "--out", tmp_path / "run"
    )
    model = trained[0] / "model"
    evaluate = peak_rss_mb(
        boxpose_bin, "eval", big, "--model", model, "--crops", "predicted",
        "--segmenter", segmenter[0] / "model", "--out", tmp_path / "eval",
    )  # fmt: skip
    print(f"decoded frames {decoded_mb:.0f} MB; peak RSS train {train:.0f}, eval {evaluate:.0f}")
    history = pd.read_csv(tmp_path / "run" / "history.csv")
    assert history.corner_recall.notna().all()
    assert train < decoded_mb / 2 and evaluate < decoded_mb / 2


def test_training_reads_the_sensor_depth_as_often_as_asked(tiny_dataset, boxpose_bin, tmp_path):
    """`[augment] sensor_depth = 1` trains every crop on its frame's simulated sensor depth: on a
    dataset rendered with the channel the same seed's losses differ from the exact depth's; on
    one without it the exact depth is read and nothing else changes (no random draw is spent).
    The segmenter, whose frames do not read it, refuses the key."""
    sensed = render_synthetic_dataset(tmp_path / "sensed", 64, 64, sensor_depth=True)
    config = (REPO / "configs" / "tiny.toml").read_text()
    assert "depth_dropout = 0.02\n" in config
    sensor_config = tmp_path / "sensor.toml"
    sensor_config.write_text(
        config.replace("depth_dropout = 0.02\n", "depth_dropout = 0.02\nsensor_depth = 1.0\n")
    )

    def losses(config: Path, dataset: Path, name: str) -> list[float]:
        out = tmp_path / f"run-{name}"
        run_boxpose(boxpose_bin, "train", "--config", config, "--dataset", dataset, "--out", out)
        return pd.read_csv(out / "history.csv").train_loss.tolist()

    exact_config = REPO / "configs" / "tiny.toml"
    assert losses(sensor_config, sensed, "sensed") != losses(exact_config, sensed, "exact")
    assert losses(sensor_config, tiny_dataset, "none") == losses(exact_config, tiny_dataset, "ref")

    segmenter_config = tmp_path / "segmenter.toml"
    text = (REPO / "configs" / "segmenter-tiny.toml").read_text()
    segmenter_config.write_text(text.replace("[augment]\n", "[augment]\nsensor_depth = 0.5\n"))
    r = run_boxpose(
        boxpose_bin, "train-segmenter", "--config", segmenter_config, "--dataset", sensed,
        "--out", tmp_path / "seg", check=False,
    )  # fmt: skip
    assert r.returncode == 1 and "sensor_depth = 0.5" in r.stderr, r.stderr
