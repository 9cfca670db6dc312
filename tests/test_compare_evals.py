"""`scripts/compare_evals.py`: two eval runs paired box by box, with McNemar's exact p."""

import subprocess
import sys

import pandas as pd

from conftest import REPO


def write_eval(folder, errors):
    """An eval.parquet with one robust row per box (scene 0, frame 0, object i): cube MSSD
    `errors[i]` on a 1 m box (None: not found)."""
    folder.mkdir()
    rows = [
        {"scene_id": 0, "frame_id": 0, "object_id": i, "method": "robust", "diameter_m": 1.0,
         "cube_mssd_m": e}
        for i, e in enumerate(errors)
    ]  # fmt: skip
    rows.append({**rows[0], "method": "paper_exact", "cube_mssd_m": 9.0})  # another fit: ignored
    pd.DataFrame(rows).to_parquet(folder / "eval.parquet")


def run(*args):
    return subprocess.run(
        [sys.executable, REPO / "scripts" / "compare_evals.py", *map(str, args)],
        capture_output=True,
        text=True,
    )


def test_pairs_count_fixed_and_new_boxes_with_mcnemar(tmp_path):
    # box 0 stays right, boxes 1–4 are fixed (one of them was not found before), box 5 breaks,
    # box 6 is only in the second run (unpaired)
    write_eval(tmp_path / "before", [0.01, 0.5, 0.5, None, 0.2, 0.05])
    write_eval(tmp_path / "after", [0.01, 0.05, 0.05, 0.05, 0.05, None, 0.01])
    r = run(tmp_path / "before", tmp_path / "after")
    assert r.returncode == 0, r.stderr
    # 5 discordant pairs, 4 fixed: p = 2 · (C(5,0) + C(5,1)) / 2⁵ = 0.375
    assert "6 boxes paired: 33.3% -> 83.3%" in r.stdout, r.stdout
    assert "fixed 4, new 1, McNemar p = 0.38" in r.stdout, r.stdout


def test_a_folder_without_an_eval_table_is_one_clear_error(tmp_path):
    write_eval(tmp_path / "before", [0.01])
    (tmp_path / "empty").mkdir()
    r = run(tmp_path / "before", tmp_path / "empty")
    assert r.returncode != 0 and "no eval.parquet" in r.stderr and "Traceback" not in r.stderr
