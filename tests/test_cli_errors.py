"""How the CLI reports a failure: one line on stderr, a non-zero exit, no backtrace, also when
RUST_BACKTRACE is set in the environment (as it often is on developer machines)."""

import os
import subprocess


def test_an_error_is_one_line_even_with_rust_backtrace_set(tmp_path, boxpose_bin):
    missing = tmp_path / "no-such-dataset"
    result = subprocess.run(
        [str(boxpose_bin), "inspect", str(missing)],
        capture_output=True,
        text=True,
        env={**os.environ, "RUST_BACKTRACE": "1"},
    )
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ") and str(missing) in lines[0]
    assert "backtrace" not in result.stderr.lower()
