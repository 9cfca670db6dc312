"""`boxpose samples` and its clients: the keypoint network's training examples served to another
framework (protocol boxpose-samples/1; boxpose_io.samples without torch, boxpose_io.torch with the
real PyTorch on the CPU, from build/torch-venv, which `make test` creates)."""

import json
import os
import subprocess
import textwrap

import numpy as np
import pytest

from boxpose_io.samples import SampleServer, SampleServerError
from conftest import REPO, render_synthetic_dataset

CONFIG = REPO / "configs" / "tiny.toml"  # 64² crops, 8 × 16² heatmaps; every other scene held out
TORCH_PYTHON = REPO / "build" / "torch-venv" / "bin" / "python"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two scenes (scene 0 held out, scene 1's three stacked boxes for training), two 160×120
    views each."""
    return render_synthetic_dataset(tmp_path_factory.mktemp("samples") / "ds", 160, 120)


@pytest.fixture
def server(dataset, boxpose_bin):
    command = [boxpose_bin, "samples", "--config", CONFIG, "--dataset", dataset]
    server = SampleServer([str(c) for c in command])
    yield server
    server.close()


def test_the_server_says_its_items_and_shapes(server):
    assert server.hello["protocol"] == "boxpose-samples/1"
    assert server.hello["train"] >= 4 and server.hello["held_out"] >= 2
    assert server.hello["input_shape"] == [4, 64, 64]
    assert server.hello["target_shape"] == [8, 16, 16]
    assert server.hello["mask_shape"] == [64, 64]


def test_an_augmented_item_is_its_seed_s_and_only_its_seed_s(server):
    first, again, other = (server.get("train", 1, seed) for seed in (5, 5, 6))
    for name in ("input", "target", "mask"):
        assert np.array_equal(first[name], again[name]), name
    assert first["crop"] == again["crop"]
    assert not np.array_equal(first["input"], other["input"]) and first["crop"] != other["crop"]
    plain, plain_again = server.get("train", 1, None), server.get("train", 1, None)
    assert np.array_equal(plain["input"], plain_again["input"])
    assert plain["turn_rad"] == 0.0


def test_an_item_s_fields_describe_its_arrays(server):
    """The target heatmap peaks where the answer's corners project through its intrinsics into
    its crop; the mask is the box's pixels of the crop, whose depth channel reads near the
    reference depth."""
    corners_checked = 0
    for split, count in (("train", server.hello["train"]), ("held_out", server.hello["held_out"])):
        for index in range(count):
            item = server.get(split, index, 3 if split == "train" else None)
            fx, fy, cx, cy = item["intrinsics"]
            x0, y0, side = item["crop"]
            heat = item["target"].max(axis=0)  # over the depth bins: 16 × 16
            cell = side / heat.shape[0]
            for corner in np.array(item["corners_camera_m"]):
                u = fx * corner[0] / corner[2] + cx + 0.5  # the window's continuous coordinates
                v = fy * corner[1] / corner[2] + cy + 0.5
                col, row = int((u - x0) // cell), int((v - y0) // cell)
                if 0 <= row < heat.shape[0] and 0 <= col < heat.shape[1]:
                    assert heat[row, col] > 0.3, (split, index, row, col)
                    corners_checked += 1
            mask = item["mask"].astype(bool)
            assert 20 < mask.sum() < mask.size, (split, index)
            depth = item["input"][3]
            # the box's own pixels: near its median depth (the depth channel is in units of 0.1 m
            # and a box here is under 0.3 m deep)
            assert np.median(np.abs(depth[mask])) < 1.5, (split, index)
            assert set(item["corner_visibility"]) <= {0, 1, 2, 3}
            assert item["scene_id"] == (1 if split == "train" else 0)
    assert corners_checked >= 40


def test_a_bad_request_is_answered_and_a_broken_one_ends_the_server(server, dataset, boxpose_bin):
    with pytest.raises(SampleServerError, match="past the .* held-out items"):
        server.get("held_out", 10**6, None)
    assert server.get("held_out", 0, None)["scene_id"] == 0  # it goes on serving
    r = subprocess.run(
        [boxpose_bin, "samples", "--config", CONFIG, "--dataset", dataset],
        input=b'{"request": 0, "split": "train", "index": 0, "colour": 1}\n',
        capture_output=True,
    )
    assert r.returncode != 0
    assert b"boxpose-samples/1: not a request" in r.stderr and b"colour" in r.stderr


def test_a_torch_training_loop_learns_from_the_samples(dataset, boxpose_bin, tmp_path):
    """The real torch (CPU), two DataLoader workers each with its own server: an item through the
    loader is the server's item of the same seed, epochs differ, a killed server is started again
    for the next item, and a small network's weighted heatmap loss falls over 40 steps."""
    assert TORCH_PYTHON.is_file(), f"{TORCH_PYTHON} is missing: `make test` creates it"
    script = textwrap.dedent(
        f"""
        import json, numpy as np, torch
        from torch.utils.data import DataLoader
        from boxpose_io.samples import SampleServer
        from boxpose_io.torch import KeypointSamples

        torch.manual_seed(0)
        torch.set_num_threads(1)
        samples = KeypointSamples({str(CONFIG)!r}, datasets=[{str(dataset)!r}],
                                  boxpose={str(boxpose_bin)!r}, seed=11)
        held_out = KeypointSamples({str(CONFIG)!r}, datasets=[{str(dataset)!r}],
                                   boxpose={str(boxpose_bin)!r}, split="held_out")
        direct = SampleServer(samples.command)
        same = bool(np.array_equal(
            samples[2]["input"].numpy(), direct.get("train", 2, samples.item_seed(2))["input"]))
        direct.close()
        first = samples[2]["input"].clone()
        samples.set_epoch(1)
        next_epoch_differs = not torch.equal(first, samples[2]["input"])
        samples.set_epoch(0)
        killed = samples._server.process.pid
        samples._server.process.kill(); samples._server.process.wait()
        again = samples[2]["input"]
        restarted = torch.equal(first, again) and samples._server.process.pid != killed

        net = torch.nn.Sequential(
            torch.nn.Conv2d(4, 16, 3, padding=1), torch.nn.ReLU(), torch.nn.MaxPool2d(2),
            torch.nn.Conv2d(16, 32, 3, padding=1), torch.nn.ReLU(), torch.nn.MaxPool2d(2),
            torch.nn.Conv2d(32, 8, 1))
        optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
        loader = DataLoader(samples, batch_size=4, shuffle=True, num_workers=2,
                            generator=torch.Generator().manual_seed(0))

        def loss_of(batch):
            target = batch["target"]
            weight = 1 + 50 * target  # as the Rust trainer weighs the corners' neighbourhoods
            return (weight * (net(batch["input"]) - target) ** 2).mean()

        losses, scenes = [], set()
        for epoch in range(20):
            samples.set_epoch(epoch)
            for batch in loader:
                loss = loss_of(batch)
                optimizer.zero_grad(); loss.backward(); optimizer.step()
                losses.append(loss.item())
                scenes.update(batch["scene_id"].tolist())
        with torch.no_grad():
            batch = next(iter(DataLoader(held_out, batch_size=len(held_out))))
            held_out_shape = list(batch["input"].shape)
        print(json.dumps(dict(
            items=len(samples), same=same, next_epoch_differs=next_epoch_differs,
            restarted=restarted,
            first=float(np.mean(losses[:4])), last=float(np.mean(losses[-4:])), steps=len(losses),
            scenes=sorted(scenes), held_out_shape=held_out_shape)))
        """
    )
    env = dict(os.environ, PYTHONPATH=str(REPO / "python"))
    r = subprocess.run(
        [TORCH_PYTHON, "-c", script], capture_output=True, text=True, env=env, timeout=600
    )
    assert r.returncode == 0, r.stderr[-3000:]
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["same"] and result["next_epoch_differs"] and result["restarted"], result
    assert result["scenes"] == [1] and result["steps"] >= 40, result
    assert result["held_out_shape"][1:] == [4, 64, 64], result
    assert result["last"] < 0.7 * result["first"], result
