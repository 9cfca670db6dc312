"""Serve a Python perception function to `boxpose search --sut python:MODULE:CALLABLE`.

    python3 -m boxpose_io.sut MODULE:CALLABLE

speaks protocol ``boxpose-sut/1`` (docs/search.md, "Your own system under test"; the Rust side
is ``rust/search/src/external.rs``) on stdin and stdout: it introduces itself, then for each
sample reads the request into a :class:`Request` and writes what ``CALLABLE(request)`` returns:

- ``None``: no box found (a failure of the system);
- a dict with ``rotation`` (3 × 3, the box's axes in the camera frame, OpenCV axes) and
  ``translation_m`` (the box's centre, metres), optionally ``size_m`` (when the system fits the
  size; else the true size is assumed), ``confidence`` and ``peaks_camera_m`` (N × 3, drawn by
  the report);
- or raises :class:`FitFailed` to say it found the box but could not fit it.

Any other exception stops the process: the search counts that sample apart as the system's error
and starts the process again. Whatever the function prints goes to stderr, so that stdout stays
the protocol's.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np

PROTOCOL = "boxpose-sut/1"


class FitFailed(Exception):
    """Raised by a perception function that found the box but could not fit a pose."""


@dataclass(frozen=True)
class Request:
    """One sample to perceive: the rendered frame and the target box."""

    scene_id: int
    #: H × W × 3 uint8, sRGB.
    rgb: np.ndarray
    #: H × W float32, metres along the optical axis, 0 where there is no surface.
    depth: np.ndarray
    #: 3 × 3 camera matrix (fx, fy, cx, cy; the top-left pixel's centre at (0, 0)).
    camera_matrix: np.ndarray
    target_object_id: int
    #: The target's true size (x, y, z extents, metres).
    box_size_m: np.ndarray
    #: With ground-truth crops: the target's visible box (x_min, y_min, x_max, y_max; max
    #: exclusive) and its H × W boolean mask; None when the system must find the box itself.
    crop: tuple[int, int, int, int] | None
    mask: np.ndarray | None


def read_request(stream: BinaryIO) -> tuple[int, Request] | None:
    """The next request and its number; None at the end of the input."""
    line = stream.readline()
    if not line:
        return None
    header = json.loads(line)
    height, width = header["height"], header["width"]

    def payload(n: int) -> bytes:
        data = stream.read(n)
        if len(data) != n:
            raise EOFError(
                f"request {header['request']}: the payload ended after {len(data)} of {n} bytes"
            )
        return data

    rgb = np.frombuffer(payload(header["rgb_bytes"]), np.uint8).reshape(height, width, 3)
    depth = np.frombuffer(payload(header["depth_bytes"]), "<f4").reshape(height, width)
    mask = None
    if header["mask_bytes"]:
        mask = np.frombuffer(payload(header["mask_bytes"]), np.uint8).reshape(height, width) != 0
    fx, fy, cx, cy = header["intrinsics"]
    crop = tuple(header["crop"]) if header["crop"] is not None else None
    return header["request"], Request(
        scene_id=header["scene_id"],
        rgb=rgb,
        depth=depth,
        camera_matrix=np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
        target_object_id=header["target_object_id"],
        box_size_m=np.asarray(header["box_size_m"], dtype=float),
        crop=crop,
        mask=mask,
    )


def answer_line(request_id: int, result: dict | None) -> dict:
    """The protocol's answer to ``result`` (what a perception function returned)."""
    if result is None:
        return {"request": request_id, "found": False}
    answer = {
        "request": request_id,
        "found": True,
        "rotation": np.asarray(result["rotation"], dtype=float).reshape(3, 3).tolist(),
        "translation_m": np.asarray(result["translation_m"], dtype=float).reshape(3).tolist(),
    }
    if result.get("size_m") is not None:
        answer["size_m"] = np.asarray(result["size_m"], dtype=float).reshape(3).tolist()
    if result.get("confidence") is not None:
        answer["confidence"] = float(result["confidence"])
    if result.get("peaks_camera_m") is not None:
        answer["peaks_camera_m"] = (
            np.asarray(result["peaks_camera_m"], dtype=float).reshape(-1, 3).tolist()
        )
    return answer


def serve(
    perceive: Callable[[Request], dict | None], name: str, stdin: BinaryIO, stdout: BinaryIO
) -> None:
    """Answers requests from ``stdin`` with ``perceive`` until the input ends."""

    def write(message: dict) -> None:
        stdout.write(json.dumps(message).encode() + b"\n")
        stdout.flush()

    write({"protocol": PROTOCOL, "name": name})
    while (read := read_request(stdin)) is not None:
        request_id, request = read
        try:
            with contextlib.redirect_stdout(sys.stderr):
                answer = answer_line(request_id, perceive(request))
        except FitFailed as e:
            answer = {"request": request_id, "error": str(e) or "the fit failed"}
        write(answer)


def load(target: str) -> Callable[[Request], dict | None]:
    """``MODULE:CALLABLE``, imported (the working directory is on the path, as with ``-m``)."""
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise SystemExit(f"boxpose_io.sut: give MODULE:CALLABLE, not {target!r}")
    function = getattr(importlib.import_module(module_name), attribute, None)
    if not callable(function):
        raise SystemExit(f"boxpose_io.sut: {module_name} has no callable {attribute!r}")
    return function


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        raise SystemExit("usage: python3 -m boxpose_io.sut MODULE:CALLABLE")
    perceive = load(argv[0])
    serve(perceive, argv[0], sys.stdin.buffer, sys.stdout.buffer)


if __name__ == "__main__":
    # run the imported module's code, not this `__main__` copy: a perception function raises
    # `boxpose_io.sut.FitFailed`, which must be the class `serve` catches
    from boxpose_io.sut import main as imported_main

    imported_main(sys.argv[1:])
