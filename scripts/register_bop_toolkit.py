"""Register a `boxpose export bop` folder with a bop_toolkit checkout, so that bop_toolkit's own
scripts (eval_calc_errors.py, eval_calc_scores.py, eval_bop19_pose.py) evaluate results on it.

bop_toolkit knows its datasets by name in `bop_toolkit_lib/dataset_params.py`; the export writes
the three entries for it in EXPORT/bop_toolkit_dataset_params.txt, and this script pastes each
where its `# N.` line says (written against the commit the file names, which
third_party/bop_toolkit holds). Run it once per export; a dataset already registered is refused.

    python scripts/register_bop_toolkit.py third_party/bop_toolkit build/bop/boxposedemo
"""

import argparse
import re
import sys
from pathlib import Path

ENTRY_FILE = "bop_toolkit_dataset_params.txt"
# Where each entry goes: after the line opening a dict (so that the dict's last entry, written
# without a trailing comma, stays as it is), or before the `else:` of the unknown-dataset error.
DICT_OPENINGS = ("    obj_ids = {\n", "    symmetric_obj_ids = {\n")
UNKNOWN_DATASET = (
    '    else:\n        raise ValueError("Unknown BOP dataset ({}).".format(dataset_name))\n'
)


def entries(text: str) -> list[str]:
    """The export's three entries, in the order of their `# 1.`, `# 2.`, `# 3.` lines."""
    parts = re.split(r"^# [123]\. .*\n", text, flags=re.MULTILINE)
    if len(parts) != 4:
        raise ValueError("expected the three entries `# 1.`, `# 2.` and `# 3.`")
    return [part if part.endswith("\n") else part + "\n" for part in parts[1:]]


def register(source: str, text: str) -> str:
    """`source` (dataset_params.py) with the entries of `text` pasted in."""
    name = re.search(r'^    elif dataset_name == ("[^"]+"):$', text, flags=re.MULTILINE)
    if name is None:
        raise ValueError("no `elif dataset_name == ...` line")
    if f"dataset_name == {name.group(1)}:" in source:
        raise ValueError(f"the dataset {name.group(1)} is already registered")
    model_ids, symmetric_ids, split = entries(text)
    for opening, entry in zip(DICT_OPENINGS, (model_ids, symmetric_ids), strict=True):
        if source.count(opening) != 1:
            raise ValueError(f"expected one line {opening.strip()!r}")
        source = source.replace(opening, opening + "        " + entry, 1)
    if source.count(UNKNOWN_DATASET) != 1:
        raise ValueError('expected one `else: raise ValueError("Unknown BOP dataset ...")`')
    return source.replace(UNKNOWN_DATASET, split + UNKNOWN_DATASET, 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("bop_toolkit", type=Path, help="bop_toolkit checkout")
    parser.add_argument("export", type=Path, help="a `boxpose export bop` folder")
    args = parser.parse_args()
    params = args.bop_toolkit / "bop_toolkit_lib" / "dataset_params.py"
    entry = args.export / ENTRY_FILE
    try:
        text = entry.read_text()
        source = params.read_text()
        registered = register(source, text)
    except (OSError, ValueError) as e:
        print(f"register_bop_toolkit: {params} with {entry}: {e}", file=sys.stderr)
        return 1
    # written beside and renamed: an interrupted run leaves the checkout as it was
    tmp = params.with_suffix(".py.tmp")
    tmp.write_text(registered)
    tmp.replace(params)
    print(f"registered {args.export.name} in {params}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
