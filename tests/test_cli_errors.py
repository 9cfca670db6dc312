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


def test_a_dataset_path_that_is_not_utf8_is_one_error_not_a_panic(tmp_path, boxpose_bin, repo):
    """A run records its configuration as TOML (UTF-8 only); training used to panic writing it."""
    dataset = os.path.join(os.fsencode(tmp_path), b"data-\xff")
    os.mkdir(dataset)
    for command, config in (("train", "tiny.toml"), ("train-segmenter", "segmenter-tiny.toml")):
        result = subprocess.run(
            [
                os.fsencode(boxpose_bin),
                command.encode(),
                b"--config",
                os.fsencode(repo / "configs" / config),
                b"--dataset",
                dataset,
                b"--out",
                os.fsencode(tmp_path / command),
            ],
            capture_output=True,
        )
        stderr = result.stderr.decode(errors="replace")
        assert result.returncode == 1, stderr
        assert "is not valid UTF-8" in stderr and "panicked" not in stderr
