"""`boxpose eval compare`: two eval runs paired box by box, with McNemar's exact p (the same
pairing as `search compare`, `boxpose_search::compare::pair`)."""

import json

import pyarrow as pa
import pyarrow.parquet as pq

from conftest import run_boxpose


def write_eval(folder, errors):
    """An eval.parquet with one robust row per box (scene 0, frame 0, object i): cube MSSD
    `errors[i]` on a 1 m box (None: not found), in the column types `boxpose eval` writes."""
    folder.mkdir()
    n = len(errors)
    table = pa.table(
        {
            "scene_id": pa.array([0] * (n + 1), pa.int64()),
            "frame_id": pa.array([0] * (n + 1), pa.int32()),
            "object_id": pa.array([*range(n), 0], pa.int32()),
            # another fit's row: ignored
            "method": pa.array(["robust"] * n + ["paper_exact"], pa.string()),
            "diameter_m": pa.array([1.0] * (n + 1), pa.float64()),
            "cube_mssd_m": pa.array([*errors, 9.0], pa.float64()),
        }
    )
    pq.write_table(table, folder / "eval.parquet")


def test_pairs_count_fixed_and_new_boxes_with_mcnemar(boxpose_bin, tmp_path):
    # box 0 stays right, boxes 1–4 are fixed (one of them was not found before), box 5 breaks,
    # box 6 is only in the second run (unpaired)
    write_eval(tmp_path / "before", [0.01, 0.5, 0.5, None, 0.2, 0.05])
    write_eval(tmp_path / "after", [0.01, 0.05, 0.05, 0.05, 0.05, None, 0.01])
    out = tmp_path / "compare.json"
    r = run_boxpose(
        boxpose_bin, "eval", "compare", tmp_path / "before", tmp_path / "after", "--json", out
    )
    assert "6 boxes paired (1 unpaired)" in r.stdout, r.stdout
    assert "before 33.3 %" in r.stdout and "after  83.3 %" in r.stdout, r.stdout
    # 5 discordant pairs, 4 fixed: p = 2 · (C(5,0) + C(5,1)) / 2⁵ = 0.375
    assert "fixed 4 (failed before only), new 1" in r.stdout and "p = 3.750e-1" in r.stdout
    c = json.loads(out.read_text())
    assert sorted(map(tuple, c["fixed"])) == [(0, 0, 1), (0, 0, 2), (0, 0, 3), (0, 0, 4)]
    assert c["new"] == [[0, 0, 5]] and c["pairs"] == 6
    # a stricter threshold: box 0 (0.01) passes, the 0.05s fail
    r = run_boxpose(
        boxpose_bin, "eval", "compare", tmp_path / "before", tmp_path / "after", "--fraction", 0.02
    )
    assert "after  16.7 %" in r.stdout, r.stdout


def test_a_folder_without_an_eval_table_or_the_fit_is_one_clear_error(boxpose_bin, tmp_path):
    write_eval(tmp_path / "before", [0.01])
    (tmp_path / "empty").mkdir()
    r = run_boxpose(
        boxpose_bin, "eval", "compare", tmp_path / "before", tmp_path / "empty", check=False
    )
    assert r.returncode != 0 and "eval.parquet" in r.stderr and "boxpose eval" in r.stderr
    before = tmp_path / "before"
    r = run_boxpose(boxpose_bin, "eval", "compare", before, before, "--method", "size", check=False)
    assert r.returncode != 0 and "no rows of the fit 'size'" in r.stderr, r.stderr
