"""A boxpose dataset's keypoint training examples as a PyTorch dataset.

    from torch.utils.data import DataLoader
    from boxpose_io.torch import KeypointSamples

    samples = KeypointSamples("configs/keypoint-slim.toml", datasets=["datasets/generated/demo"])
    loader = DataLoader(samples, batch_size=8, shuffle=True, num_workers=2)
    for epoch in range(10):
        samples.set_epoch(epoch)          # another augmentation of every item
        for batch in loader:
            batch["input"], batch["target"]   # [B, 4, S, S], [B, D, S/4, S/4]

Each item is what ``boxpose train`` computes for the same config, computed by the same code:
``boxpose samples`` (protocol ``boxpose-samples/1``: :mod:`boxpose_io.samples`) serves them, one
process per DataLoader worker, started in the worker on its first item. The items are
the RGB-D crop as the network's input, the target heatmap, the box's mask in the crop, its true
corners with their visibility, the intrinsics and the crop window (docs/learning.md, "Training in
PyTorch"). Frames are read from the dataset's shards when an item needs them, not ahead. A server
that ends (killed, crashed) is started again for the next item, which is tried once more.

Needs torch (not a dependency of boxpose: install the build you train with).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from boxpose_io.binary import find_boxpose
from boxpose_io.samples import SampleServer, SampleServerError


class KeypointSamples(torch.utils.data.Dataset):
    """The keypoint network's examples of ``config``'s datasets (or ``datasets``), as
    ``boxpose train --config CONFIG [--dataset …] [--repeat …]`` draws them.

    ``split``: ``"train"`` (the training scenes, each counted ``repeat`` times) or
    ``"held_out"`` (every ``val_modulus``-th scene, as training validates on). Training items
    are augmented as training augments them (the config's ``[augment]``), from a seed that depends
    only on (``seed``, the epoch of :meth:`set_epoch`, the index): the same item of the same epoch
    is the same crop in every run and every worker. ``augment=False`` reads every item as
    validation does.

    An item is a dict of tensors: ``input`` [4, S, S] float32 (R, G, B normalised, depth relative
    to ``reference_depth_m``), ``target`` [D, S/4, S/4] float32, ``mask`` [S, S] uint8 (1 on the
    box), ``corners_camera_m`` [8, 3] float64 (the target's Gaussian centres, in the camera's
    frame: the turned camera's when the augmentation turned it), ``corner_visibility`` [8] int64
    (0 visible, 1 occluded by another box, 2 self-occluded, 3 outside the image),
    ``intrinsics`` [4] float64 (fx, fy, cx, cy), ``crop`` [3] float64 (x0, y0, side of the window;
    input pixel (r, c) sees the image at (x0 + (c + ½)·side/S − ½, y0 + (r + ½)·side/S − ½) in the
    intrinsics' pixel coordinates), ``box_size_m`` [3], and the scalars ``turn_rad``,
    ``reference_depth_m``, ``scene_id``, ``frame_id``, ``object_id``.
    """

    def __init__(
        self,
        config: str | os.PathLike,
        datasets: Sequence[str | os.PathLike] = (),
        repeat: Sequence[int] = (),
        split: str = "train",
        augment: bool = True,
        seed: int = 0,
        boxpose: str | os.PathLike | None = None,
    ):
        if split not in ("train", "held_out"):
            raise ValueError(f"split must be 'train' or 'held_out', got {split!r}")
        self.command = [str(find_boxpose(boxpose)), "samples", "--config", str(Path(config))]
        for dataset in datasets:
            self.command += ["--dataset", str(Path(dataset))]
        if repeat:
            self.command += ["--repeat", ",".join(str(int(k)) for k in repeat)]
        self.split, self.augment, self.seed, self.epoch = split, augment, int(seed), 0
        server = SampleServer(self.command)
        self.hello = server.hello
        server.close()
        self._server: SampleServer | None = None
        self._server_pid: int | None = None

    def __len__(self) -> int:
        return self.hello["train" if self.split == "train" else "held_out"]

    def set_epoch(self, epoch: int) -> None:
        """Draw the next augmentation of every item (as ``DistributedSampler.set_epoch``). With
        DataLoader workers that persist, call it before the loader starts the epoch's workers,
        i.e. without ``persistent_workers``."""
        self.epoch = int(epoch)

    def item_seed(self, index: int) -> int | None:
        """The augmentation's seed of item ``index`` this epoch (None when not augmented)."""
        if self.split != "train" or not self.augment:
            return None
        state = np.random.SeedSequence([self.seed, self.epoch, index]).generate_state(1, np.uint64)
        return int(state[0])

    def _connection(self) -> SampleServer:
        # one process per process that reads items: a DataLoader worker starts its own
        if self._server is None or self._server_pid != os.getpid():
            self._server, self._server_pid = SampleServer(self.command), os.getpid()
        return self._server

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < len(self):
            raise IndexError(f"item {index} of {len(self)}")
        request = (self.split, int(index), self.item_seed(index))
        try:
            answer = self._connection().get(*request)
        except SampleServerError:
            if self._server.running:
                raise  # answered: the request's own error
            # the process ended (killed for memory, crashed): a fresh one tries the item once more,
            # and a crash of every try still raises, with the new process's message
            self._server.close()
            self._server = None
            answer = self._connection().get(*request)
        item = {name: torch.from_numpy(answer[name].copy()) for name in ("input", "target", "mask")}
        for name, dtype in (
            ("corners_camera_m", torch.float64),
            ("corner_visibility", torch.int64),
            ("intrinsics", torch.float64),
            ("crop", torch.float64),
            ("box_size_m", torch.float64),
        ):
            item[name] = torch.tensor(answer[name], dtype=dtype)
        for name in ("turn_rad", "reference_depth_m", "scene_id", "frame_id", "object_id"):
            item[name] = answer[name]
        return item

    def __getstate__(self) -> dict:
        # a worker started by spawn gets the dataset without the parent's process
        state = dict(self.__dict__)
        state["_server"] = state["_server_pid"] = None
        return state

    def __del__(self) -> None:
        server = getattr(self, "_server", None)
        if server is not None and self._server_pid == os.getpid():
            server.close()
