"""Packaging: the `boxpose` distribution (root pyproject.toml, maturin) — its packages import from
this tree in .venv (`make setup`), `pip install .` puts all of them into a fresh venv, and the
compiled module's type stub (python/boxpose/boxpose.pyi) matches the compiled module: same
functions, same parameters (names, order, kinds, defaults)."""

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
from boxpose import boxpose as compiled

REPO = Path(__file__).resolve().parent.parent
PACKAGES = REPO / "python"
STUB = PACKAGES / "boxpose" / "boxpose.pyi"
PURE_PACKAGES = ("boxpose_io", "boxpose_ray", "drake_scenes", "blender_scripts")

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
        for name, value in vars(compiled).items()
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
    missing = {n for n in stub_public_names() if not hasattr(compiled, n)}
    assert not missing, (
        f"{STUB.name} declares names the compiled module lacks (prefix stub-only types with _)"
    )


def test_the_stub_all_matches_the_module_all():
    """`__all__` (PyO3 lists every added function) decides what `import boxpose` re-exports."""
    [declared] = [
        ast.literal_eval(node.value)
        for node in stub_tree().body
        if isinstance(node, ast.Assign)
        and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
    ]
    assert sorted(declared) == sorted(compiled.__all__), f"{STUB.name}: __all__ differs"


def test_the_package_is_the_compiled_module_and_read_dataset():
    assert sorted(boxpose.__all__) == sorted([*compiled.__all__, "DatasetError", "read_dataset"])
    assert all(getattr(boxpose, name) is getattr(compiled, name) for name in compiled.__all__)
    import boxpose_io

    assert boxpose.read_dataset is boxpose_io.read_dataset


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


def test_the_compiled_module_sits_beside_its_stub():
    """`maturin develop` builds the compiled module into python/boxpose/, where the stub and the
    py.typed marker are: a module imported from elsewhere is a stale install (`make rust`)."""
    assert Path(compiled.__file__).parent == STUB.parent, (
        f"boxpose.boxpose imported from {compiled.__file__}, not {STUB.parent}: run `make rust`"
    )
    assert (STUB.parent / "py.typed").is_file(), f"{STUB.parent} has no py.typed marker"


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
        f"the Python packages do not import outside the repository: run `make setup`\n{r.stderr}"
    )
    files = {name: Path(f) for name, f in json.loads(r.stdout).items()}
    for name in PURE_PACKAGES:
        assert files[name] == PACKAGES / name / "__init__.py", f"{name} imported from {files[name]}"


def test_pyproject_lists_every_package_folder():
    """maturin's list of the pure-Python packages is written by hand: a new package folder in
    python/ must be added, or `pip install .` would leave it out."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["maturin"]
    found = {init.parent.name for init in PACKAGES.glob("*/__init__.py")} - {"boxpose"}
    assert set(config["python-packages"]) == found == set(PURE_PACKAGES)
    assert (config["python-source"], config["module-name"]) == ("python", "boxpose.boxpose")


def test_pip_install_puts_every_package_into_a_fresh_venv(tmp_path):
    """`pip install .` (maturin builds the wheel) into a new venv with nothing else: boxpose
    with its stub, read_dataset reading a dataset, and every package, imported from the venv."""
    from test_dataset_contract import synthetic_rows, write_dataset

    dataset = tmp_path / "dataset"
    write_dataset(dataset, synthetic_rows(__import__("numpy").random.default_rng(0)))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    # the geometry crate's build from `make setup` is reused; requirements.txt's pins as
    # constraints: the versions that install together (and are in pip's cache)
    env["CARGO_TARGET_DIR"] = str(REPO / "target" / "maturin")
    r = subprocess.run(
        [venv / "bin" / "pip", "install", "--quiet", "-c", REPO / "requirements.txt", REPO],
        env=env, capture_output=True, text=True, timeout=1200,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    probe = (
        "import importlib.util, json, sys\n"
        "from pathlib import Path\n"
        "import boxpose\n"
        "tables = boxpose.read_dataset(sys.argv[1])\n"
        "package = Path(boxpose.__file__).parent\n"
        "print(json.dumps({\n"
        "    'rows': {name: t.num_rows for name, t in tables.items()},\n"
        "    'origins': {m: importlib.util.find_spec(m).origin for m in sys.argv[2:]},\n"
        "    'typed': sorted(\n"
        "        p.name for p in package.iterdir() if p.name.endswith(('.pyi', '.typed'))\n"
        "    ),\n"
        "    'corners': boxpose.box_corners([0.1, 0.2, 0.3]).shape,\n"
        "}))\n"
    )
    r = subprocess.run(
        [venv / "bin" / "python", "-c", probe, dataset, "boxpose", *PURE_PACKAGES],
        cwd=tmp_path, env=env, capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout)
    expected = boxpose.read_dataset(dataset)
    assert found["rows"] == {name: t.num_rows for name, t in expected.items()}
    assert found["typed"] == ["boxpose.pyi", "py.typed"] and found["corners"] == [8, 3]
    site = next((venv / "lib").glob("python3*/site-packages"))
    for name, origin in found["origins"].items():
        assert Path(origin).is_relative_to(site), f"{name} imported from {origin}, not the venv"
