"""The first build (`make setup`) compiles the workspace without its tests and benchmarks, and
`make test` compiles those afterwards. That saves the setup the dev-dependencies (criterion,
proptest, tempfile) only if they add no feature to a crate both builds share: otherwise each
build recompiles that crate and everything above it (burn-flex, arrow, parquet) in turn.
`rust/workspace-hack` switches those features on for both; this test finds any it misses."""

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def _features(edges: str) -> dict[tuple[str, str, bool], set[str]]:
    """Every package of the workspace's graph over `edges` with the features cargo enables."""
    out = subprocess.run(
        [
            "cargo",
            "tree",
            "--workspace",
            "--edges",
            edges,
            "--format",
            "{p} {f}",
            "--prefix",
            "none",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    features: dict[tuple[str, str, bool], set[str]] = {}
    for line in out.splitlines():
        # "name vX.Y.Z [(proc-macro)] [(/path)] [feature,feature…] [(*)]"
        words = line.replace("(*)", "").split()
        if not words:
            continue
        name, version, rest = words[0], words[1], words[2:]
        proc_macro = "(proc-macro)" in rest
        enabled = [w for w in rest if not w.startswith("(")]
        assert len(enabled) <= 1, f"unexpected `cargo tree` line: {line!r}"
        key = (name, version, proc_macro)
        features.setdefault(key, set()).update(",".join(enabled).split(",") if enabled else ())
    return features


def test_the_dev_dependencies_add_no_feature_to_a_crate_the_setup_build_compiles():
    without_dev = _features("normal,build")
    with_dev = _features("normal,build,dev")
    assert any(name == "burn-flex" for name, _, _ in without_dev), "the graph was not parsed"
    added = {
        f"{name} {version}": sorted(with_dev[key] - enabled)
        for key, enabled in without_dev.items()
        for name, version, _ in [key]
        if with_dev.get(key, enabled) != enabled
    }
    assert not added, (
        f"dev-dependencies switch on features of crates the setup build compiles: {added}; "
        "add them to rust/workspace-hack/Cargo.toml"
    )
