"""Systems under test that misbehave on purpose, for tests/test_external_sut.py: served by
`python -m boxpose_io.sut tests.sut_fixtures:misbehaves` from the repository root."""

import time

from boxpose_io.sut import FitFailed, Request


def misbehaves(request: Request) -> dict | None:
    """By scene id modulo 4: finds nothing (printing to stdout on the way, which must not reach
    the protocol), crashes, hangs, or cannot fit."""
    kind = request.scene_id % 4
    if kind == 0:
        print("a chatty system: this line must go to stderr")
        return None
    if kind == 1:
        raise RuntimeError("the system crashed")
    if kind == 2:
        time.sleep(120)
        return None
    raise FitFailed("too few points")
