"""Where the ``boxpose`` binary is, for the Python stages that run it."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DEFAULT_BOXPOSE = REPO / "target" / "release" / "boxpose"


def find_boxpose(boxpose: str | os.PathLike | None = None) -> Path:
    """``boxpose`` if given, else the repository's release build, else the one on PATH; a
    FileNotFoundError that says how to get one otherwise."""
    candidates = [Path(boxpose)] if boxpose is not None else [DEFAULT_BOXPOSE]
    if boxpose is None and (on_path := shutil.which("boxpose")):
        candidates.append(Path(on_path))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"the boxpose binary is not at {candidates[0]}: build it with `make rust`, or pass its path"
    )
