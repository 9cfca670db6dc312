"""The Rust tree's structure as docs/design.md describes it: the modules of every crate depend
one way (no module uses one that uses it back), and the crate graph drawn in the design document
is the one the Cargo manifests declare."""

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CRATES = sorted(p.parent for p in (ROOT / "rust").glob("*/Cargo.toml"))


def _without_tests_and_comments(text: str) -> str:
    """The module's own code: test modules (from `#[cfg(test)]` on) may use anything."""
    text = text.split("#[cfg(test)]", 1)[0]
    return re.sub(r"//[^\n]*", "", text)


def _reexports(src: Path) -> dict[str, str]:
    """Item → module of the crate root's `pub use module::{Item, …}` lines."""
    lib = src / "lib.rs"
    found: dict[str, str] = {}
    if not lib.exists():
        return found
    for module, items in re.findall(r"pub use ([a-z_]+)::\{?([^;}]*)\}?;", lib.read_text()):
        for item in re.split(r"[,\s]+", items):
            if item:
                found[item.split("::")[-1]] = module
    return found


def module_graph(crate: Path) -> dict[str, set[str]]:
    """Each module of the crate's src/ (by file stem) and the crate modules it names."""
    src = crate / "src"
    reexports = _reexports(src)
    graph: dict[str, set[str]] = {}
    for path in sorted(src.glob("*.rs")):
        name = path.stem
        if name in ("lib", "main"):
            continue
        text = _without_tests_and_comments(path.read_text())
        used = set(re.findall(r"crate::([a-z_]+)", text))
        for group in re.findall(r"crate::\{([^}]*)\}", text):
            for item in re.split(r"[,\s]+", group):
                head = item.split("::")[0]
                if head:
                    used.add(reexports.get(head, head))
        modules = {p.stem for p in src.glob("*.rs")}
        graph[name] = {m for m in used if m in modules and m != name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    done: set[str] = set()

    def visit(module: str, path: list[str]) -> list[str] | None:
        if module in done:
            return None
        if module in path:
            return path[path.index(module) :] + [module]
        for used in sorted(graph.get(module, ())):
            if cycle := visit(used, path + [module]):
                return cycle
        done.add(module)
        return None

    for module in sorted(graph):
        if cycle := visit(module, []):
            return cycle
    return None


@pytest.mark.parametrize("crate", CRATES, ids=lambda p: p.name)
def test_the_modules_of_every_crate_depend_one_way(crate):
    cycle = _cycle(module_graph(crate))
    assert cycle is None, f"{crate.name}: module cycle {' → '.join(cycle)}"


def test_the_cycle_check_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def _manifest_edges() -> set[tuple[str, str]]:
    edges = set()
    for crate in CRATES:
        manifest = tomllib.loads((crate / "Cargo.toml").read_text())
        name = manifest["package"]["name"]
        for dependency, spec in manifest.get("dependencies", {}).items():
            if isinstance(spec, dict) and "path" in spec and dependency != "boxpose-workspace-hack":
                edges.add((name, dependency))
    return edges


def _design_doc_edges() -> set[tuple[str, str]]:
    text = (ROOT / "docs" / "design.md").read_text()
    block = text.split("## Crate graph", 1)[1].split("```mermaid", 1)[1].split("```", 1)[0]
    labels: dict[str, str] = {}
    for node, label in re.findall(r'(\w+)\["?([^"\]]+)"?\]', block):
        labels[node] = label.split()[0]
    edges = set()
    for line in block.splitlines():
        if "-->" not in line:
            continue
        left, right = (re.match(r"\s*(\w+)", side).group(1) for side in line.split("-->"))
        edges.add((labels[left], labels[right]))
    return edges


def test_the_design_docs_crate_graph_is_the_manifests():
    manifests, drawn = _manifest_edges(), _design_doc_edges()
    assert len(manifests) >= 15
    assert drawn == manifests, (
        f"docs/design.md draws {sorted(drawn - manifests)} that no Cargo.toml declares "
        f"and lacks {sorted(manifests - drawn)}"
    )


def long_functions(text: str, limit: int) -> list[tuple[str, int]]:
    """The functions of a rustfmt-formatted source longer than `limit` lines, signature to
    closing brace (a function ends at the first `}` line at its own indentation)."""
    lines = text.splitlines()
    found = []
    i = 0
    while i < len(lines):
        start = re.match(r"^(\s*)(?:pub(?:\([a-z]+\))? )?(?:const )?fn (\w+)", lines[i])
        if start is None:
            i += 1
            continue
        end = i
        while end < len(lines) and lines[end] != start.group(1) + "}":
            end += 1
        if end - i + 1 > limit:
            found.append((start.group(2), end - i + 1))
        i = end + 1
    return found


def test_the_binary_has_no_function_over_80_lines():
    # the binary parses, prints and plots; work long enough to need more belongs to a library
    long = {
        f"{src.relative_to(ROOT)}: {name}": n
        for src in sorted((ROOT / "rust" / "cli" / "src").rglob("*.rs"))
        for name, n in long_functions(src.read_text(), 80)
    }
    assert not long, long


def test_the_length_check_finds_a_long_function():
    body = "\n".join(["    let x = 1;"] * 80)
    text = f"fn short() {{\n}}\n\npub fn long() {{\n{body}\n}}\n"
    assert long_functions(text, 80) == [("long", 82)]
