"""Packaging: the pure-Python packages are installed (root pyproject.toml, editable install by
`make setup`), and the `boxpose` module's type stub (rust/python/boxpose.pyi) matches the
compiled module: same functions, same parameters (names, order, kinds, defaults)."""

import ast
import inspect
import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import boxpose

REPO = Path(__file__).resolve().parent.parent
STUB = REPO / "rust" / "python" / "boxpose.pyi"
PURE_PACKAGES = {
    "boxpose_io": REPO / "python",
    "boxpose_ray": REPO / "python",
    "drake_scenes": REPO,
    "blender_scripts": REPO,
}

# ---------------------------------------------------------------- the stub and the compiled module

_KINDS = {
    "posonlyargs": inspect.Parameter.POSITIONAL_ONLY,
    "args": inspect.Parameter.POSITIONAL_OR_KEYWORD,
    "vararg": inspect.Parameter.VAR_POSITIONAL,
    "kwonlyargs": inspect.Parameter.KEYWORD_ONLY,
    "kwarg": inspect.Parameter.VAR_KEYWORD,
}
_NO_DEFAULT = "<no default>"


def _typed(value):
    """A default compared with its type: 2 and 2.0, or 0 and False, are different defaults."""
    return _NO_DEFAULT if value is _NO_DEFAULT else (type(value).__name__, value)


def stub_tree() -> ast.Module:
    return ast.parse(STUB.read_text(), filename=str(STUB))


def stub_functions() -> dict[str, ast.FunctionDef]:
    return {n.name: n for n in stub_tree().body if isinstance(n, ast.FunctionDef)}


def stub_public_names() -> set[str]:
    """Every public name the stub defines (functions, classes, aliases): all must exist at run
    time, stub-only helper types are `_`-prefixed."""
    names = set()
    for node in stub_tree().body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return {n for n in names if not n.startswith("_")}


def stub_parameters(node: ast.FunctionDef) -> list[tuple[str, inspect._ParameterKind, object]]:
    """(name, kind, default) of each parameter, in signature order, parsed (never imported)."""
    a = node.args
    positional = a.posonlyargs + a.args
    defaults = [_NO_DEFAULT] * (len(positional) - len(a.defaults)) + [
        ast.literal_eval(d) for d in a.defaults
    ]
    params = []
    for i, arg in enumerate(positional):
        kind = _KINDS["posonlyargs" if i < len(a.posonlyargs) else "args"]
        params.append((arg.arg, kind, _typed(defaults[i])))
    if a.vararg:
        params.append((a.vararg.arg, _KINDS["vararg"], _NO_DEFAULT))
    for arg, default in zip(a.kwonlyargs, a.kw_defaults, strict=True):
        value = _NO_DEFAULT if default is None else ast.literal_eval(default)
        params.append((arg.arg, _KINDS["kwonlyargs"], _typed(value)))
    if a.kwarg:
        params.append((a.kwarg.arg, _KINDS["kwarg"], _NO_DEFAULT))
    return params


def runtime_functions() -> dict[str, object]:
    return {
        name: value
        for name, value in vars(boxpose).items()
        if not name.startswith("_") and callable(value)
    }


def runtime_parameters(function) -> list[tuple[str, inspect._ParameterKind, object]]:
    """From `__text_signature__`, which PyO3 writes from `#[pyo3(signature = ...)]`."""
    return [
        (
            p.name,
            p.kind,
            _typed(_NO_DEFAULT if p.default is inspect.Parameter.empty else p.default),
        )
        for p in inspect.signature(function).parameters.values()
    ]


def test_the_stub_declares_exactly_the_module_functions():
    stub, runtime = set(stub_functions()), set(runtime_functions())
    assert runtime, "the compiled boxpose module exports no functions"
    assert not runtime - stub, f"functions of the compiled module missing from {STUB.name}"
    assert not stub - runtime, f"functions of {STUB.name} the compiled module does not export"


def test_every_public_stub_name_exists_at_run_time():
    missing = {n for n in stub_public_names() if not hasattr(boxpose, n)}
    assert not missing, (
        f"{STUB.name} declares names that `import boxpose` lacks (prefix stub-only types with _)"
    )


def test_the_stub_all_matches_the_module_all():
    """`__all__` (PyO3 lists every added function) decides what `from boxpose import *` takes."""
    [declared] = [
        ast.literal_eval(node.value)
        for node in stub_tree().body
        if isinstance(node, ast.Assign)
        and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
    ]
    assert sorted(declared) == sorted(boxpose.__all__), f"{STUB.name}: __all__ differs"


@pytest.mark.parametrize("name", sorted(runtime_functions()))
def test_stub_signature_matches_the_compiled_function(name):
    function = runtime_functions()[name]
    assert function.__text_signature__, f"boxpose.{name} has no __text_signature__"
    node = stub_functions().get(name)
    if node is None:
        pytest.fail(f"boxpose.{name} is missing from {STUB.name}")
    assert stub_parameters(node) == runtime_parameters(function), (
        f"{STUB.name}: the parameters of {name} (name, kind, default) differ from the module's "
        f"{inspect.signature(function)}"
    )


@pytest.mark.parametrize("name", sorted(stub_functions()))
def test_stub_functions_are_fully_annotated(name):
    node = stub_functions()[name]
    a = node.args
    arguments = a.posonlyargs + a.args + a.kwonlyargs + [x for x in (a.vararg, a.kwarg) if x]
    unannotated = [arg.arg for arg in arguments if arg.annotation is None]
    assert not unannotated, f"{STUB.name}: {name}'s parameters {unannotated} have no type"
    assert node.returns is not None, f"{STUB.name}: {name} has no return type"


def test_the_installed_module_ships_this_stub():
    """maturin installs the stub as boxpose/__init__.pyi with a py.typed marker; a different
    copy there means the module was not rebuilt since the stub changed (`make rust`)."""
    package = Path(boxpose.__file__).parent
    installed = package / "__init__.pyi"
    assert installed.is_file(), f"{installed} is missing: rebuild the module (`make rust`)"
    assert (package / "py.typed").is_file(), f"{package} has no py.typed marker"
    assert installed.read_text() == STUB.read_text(), (
        f"{installed} differs from {STUB.relative_to(REPO)}: rebuild the module (`make rust`)"
    )


# ----------------------------------------------------------------------- the pure-Python packages


def test_the_packages_import_from_any_directory(tmp_path):
    """No PYTHONPATH, no sys.path edits, a working directory outside the repository: the
    editable install alone finds the packages (and the ones in this tree, not other copies)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    code = (
        "import json, boxpose_io, boxpose_ray, drake_scenes, blender_scripts, drake_scenes.cli\n"
        "print(json.dumps({m.__name__: m.__file__ for m in "
        "(boxpose_io, boxpose_ray, drake_scenes, blender_scripts)}))\n"
        "assert boxpose_io.TABLES, 'schema.json not loaded'\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert r.returncode == 0, (
        "the Python packages do not import outside the repository: run `make setup` "
        f"(pip install --no-deps -e .)\n{r.stderr}"
    )
    files = {name: Path(f) for name, f in json.loads(r.stdout).items()}
    for name, root in PURE_PACKAGES.items():
        assert files[name] == root / name / "__init__.py", f"{name} imported from {files[name]}"


def test_pyproject_lists_every_package_folder():
    """setuptools' package list is written by hand (two roots): a new subpackage must be added,
    or a wheel build would leave it out."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    found = {
        ".".join(init.parent.relative_to(root).parts)
        for name, root in PURE_PACKAGES.items()
        for init in (root / name).rglob("__init__.py")
    }
    assert listed == found, f"pyproject.toml packages {sorted(listed)} != folders {sorted(found)}"
    assert config["package-dir"] == {
        name: str(root.relative_to(REPO) / name)
        for name, root in PURE_PACKAGES.items()
        if root != REPO
    }
    assert "schema.json" in config["package-data"]["boxpose_io"]
