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


def run_into_closed_pipe(boxpose_bin, *args) -> subprocess.CompletedProcess:
    """Runs boxpose with its stdout a pipe nobody reads any more, as `boxpose … | head -1` leaves
    it once head has exited: every write fails with EPIPE."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run(
            [str(boxpose_bin), *map(str, args)], stdout=write_end, stderr=subprocess.PIPE, text=True
        )
    finally:
        os.close(write_end)


def test_output_into_a_closed_pipe_ends_quietly(tmp_path, boxpose_bin):
    import boxpose_io
    from blender_scripts.synthetic import synthetic_scene
    from conftest import tiny_recipe

    scene, objects = synthetic_scene(0, tiny_recipe(64, 64, 1), 2, seed=1)
    for table, rows in (("scenes", [scene]), ("objects", objects)):
        boxpose_io.write_shard(
            boxpose_io.shard_path(tmp_path, table, 0, 1), boxpose_io.table_from_rows(table, rows)
        )
    for args in (("dump", tmp_path), ("schema", "--markdown"), ("schema",)):
        result = run_into_closed_pipe(boxpose_bin, *args)
        assert (result.returncode, result.stderr) == (0, ""), (args, result.stderr)


def test_eval_geometry_out_is_a_file_path(tmp_path, boxpose_bin):
    result = subprocess.run(
        [str(boxpose_bin), "eval-geometry", str(tmp_path / "dataset"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert f"--out {tmp_path} is a folder" in line and "eval_geometry.parquet" in line, line
    assert "Is a directory" not in line


def test_the_shipped_defaults_are_found_from_any_working_folder(tmp_path, boxpose_bin):
    """The defaults (a search space's name, its recipe, --model) are paths under the repository
    root; run from another folder, the command finds them there."""
    result = subprocess.run(
        [
            str(boxpose_bin),
            "search",
            "single_box",
            "--samples",
            "1",
            "--batch-size",
            "1",
            "--threads",
            "1",
            "--out",
            "run",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "run" / "summary.json").is_file()
    # a name that is nowhere is still one error naming what was asked for and what exists
    result = subprocess.run(
        [str(boxpose_bin), "search", "no_such_space", "--out", "run2"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert result.returncode == 1 and "no_such_space" in result.stderr
    assert "single_box" in result.stderr and not (tmp_path / "run2").exists()


def test_the_top_level_help_says_how_datasets_are_made_and_what_out_means(boxpose_bin):
    # the trial found no way from `--help` to `make scenes`, and four meanings of --out unnamed
    text = subprocess.run(
        [boxpose_bin, "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "make scenes RECIPE=NAME" in text and "scripts/make_scenes.py" in text
    for command in ("eval-geometry", "export", "predict", "search", "train", "improve"):
        assert command in text.split("--out is", 1)[1], command
