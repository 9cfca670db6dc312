"""The client of ``boxpose samples`` (protocol ``boxpose-samples/1``, specified in
``rust/learn/src/sample_server.rs``): the keypoint network's training examples as ``boxpose
train`` computes them, as NumPy arrays, for any framework's loop. :mod:`boxpose_io.torch` wraps it
in a PyTorch dataset.

    server = SampleServer(["target/release/boxpose", "samples", "--config", "configs/tiny.toml"])
    item = server.get("train", 0, seed=7)      # item["input"], item["target"], item["mask"], …
    server.close()
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np

PROTOCOL = "boxpose-samples/1"


class SampleServerError(RuntimeError):
    """The ``boxpose samples`` process could not answer (it names what went wrong)."""


class SampleServer:
    """One ``boxpose samples`` process: :meth:`get` sends a request and reads its answer."""

    def __init__(self, command: Sequence[str]):
        self.process = subprocess.Popen(
            list(command), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        first = self.process.stdout.readline()
        if not first:
            raise SampleServerError(f"`{' '.join(command)}` ended: {self._stderr()}")
        self.hello = json.loads(first)
        if self.hello.get("protocol") != PROTOCOL:
            self.close()
            raise SampleServerError(f"expected protocol {PROTOCOL}, got {self.hello!r}")
        self.requests = 0

    @property
    def running(self) -> bool:
        """Whether the process is still there (an answered error leaves it serving)."""
        return self.process.poll() is None

    def _stderr(self) -> str:
        self.process.wait(timeout=30)
        return self.process.stderr.read().decode(errors="replace").strip()

    def get(self, split: str, index: int, seed: int | None) -> dict:
        """The answer to one request: its JSON fields, and ``input``, ``target`` and ``mask`` as
        NumPy arrays of the hello's shapes."""
        request = {"request": self.requests, "split": split, "index": index, "seed": seed}
        self.requests += 1
        try:
            self.process.stdin.write((json.dumps(request) + "\n").encode())
            self.process.stdin.flush()
        except BrokenPipeError:
            raise SampleServerError(f"boxpose samples ended: {self._stderr()}") from None
        line = self.process.stdout.readline()
        if not line:
            raise SampleServerError(f"boxpose samples ended: {self._stderr()}")
        answer = json.loads(line)
        if "error" in answer:
            raise SampleServerError(answer["error"])
        sizes = answer.pop("payload_bytes")
        shapes = (self.hello["input_shape"], self.hello["target_shape"], self.hello["mask_shape"])
        for name, dtype, size, shape in zip(
            ("input", "target", "mask"), ("<f4", "<f4", "u1"), sizes, shapes, strict=True
        ):
            answer[name] = np.frombuffer(_read_exactly(self.process.stdout, size), dtype).reshape(
                shape
            )
        return answer

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.stdin.close()
            self.process.wait(timeout=30)
        self.process.stdout.close()
        self.process.stderr.close()


def _read_exactly(stream: BinaryIO, size: int) -> bytes:
    data = stream.read(size)
    if len(data) != size:
        raise SampleServerError(f"boxpose samples sent {len(data)} of {size} payload bytes")
    return data
