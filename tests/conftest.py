"""Shared fixtures of the end-to-end tests: the built `boxpose` binary and the repository root."""

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def boxpose_bin() -> Path:
    """The release binary built by `make setup` (override with BOXPOSE_BIN)."""
    path = Path(os.environ.get("BOXPOSE_BIN", REPO / "target" / "release" / "boxpose"))
    if not path.is_file():
        pytest.fail(f"{path} is missing: run `make setup` (or `cargo build --release`) first")
    return path


def run_boxpose(boxpose_bin: Path, *args, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run([str(boxpose_bin), *map(str, args)], capture_output=True, text=True)
    if check and result.returncode != 0:
        raise AssertionError(f"boxpose {' '.join(map(str, args))} failed:\n{result.stderr}")
    return result
