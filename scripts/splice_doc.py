"""Replace the generated column reference between the markers of a Markdown file."""

import sys
from pathlib import Path

BEGIN = "<!-- BEGIN GENERATED COLUMNS: `make schema` rewrites this part -->"
END = "<!-- END GENERATED COLUMNS -->"

doc_path, generated_path = map(Path, sys.argv[1:3])
doc = doc_path.read_text()
head, rest = doc.split(BEGIN, 1)
_, tail = rest.split(END, 1)
# Written beside the document and renamed: a kill never leaves it half written.
tmp = doc_path.with_name(doc_path.name + ".tmp")
tmp.write_text(f"{head}{BEGIN}\n{generated_path.read_text().strip()}\n{END}{tail}")
tmp.replace(doc_path)
