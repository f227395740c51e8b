"""Shared fixtures: the `boucwen` binary the results are checked against, and the records.

The binary is `$BOUCWEN_CLI`, else the newest `boucwen` under the workspace's target
directory (`$CARGO_TARGET_DIR`, else `target/`): build it with `cargo build -p boucwen-cli`.
"""

import json
import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[3]
SHARED = ROOT.parent / "shared"
BENCHMARK = SHARED / "data" / "bouc-wen-benchmark" / "train.csv"


def _find_cli():
    given = os.environ.get("BOUCWEN_CLI")
    if given:
        return pathlib.Path(given)
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    found = [p for p in (target / "release" / "boucwen", target / "debug" / "boucwen") if p.is_file()]
    if not found:
        pytest.fail(
            f"no boucwen binary under {target} (cargo build -p boucwen-cli) and BOUCWEN_CLI not set: "
            "the tests compare with it"
        )
    return max(found, key=lambda p: p.stat().st_mtime)


class Cli:
    """The `boucwen` binary: run it, read its stdout, its JSON or its error."""

    def __init__(self, path):
        self.path = path

    def run(self, *args, ok=True, cwd=None):
        p = subprocess.run([str(self.path), *map(str, args)], capture_output=True, text=True, cwd=cwd)
        if ok and p.returncode != 0:
            raise AssertionError(f"boucwen {' '.join(map(str, args))} failed: {p.stderr}")
        return p

    def json(self, *args, **kw):
        return json.loads(self.run(*args, "--json", **kw).stdout)


@pytest.fixture(scope="session")
def cli():
    return Cli(_find_cli())


@pytest.fixture(scope="session")
def benchmark():
    if not BENCHMARK.is_file():
        pytest.fail(f"{BENCHMARK} is missing: the tests read the Bouc-Wen benchmark's training record")
    return str(BENCHMARK)


@pytest.fixture(scope="session")
def sine23(cli, tmp_path_factory):
    """A record of the virtual bimorph driven by a 23 Hz sine (1 V, 8 s, 1 kHz)."""
    path = tmp_path_factory.mktemp("records") / "s23.csv"
    cli.run("simulate", "--freq", 23, "--seconds", 8, "--out", path)
    return str(path)


def without(value, keys):
    """`value` with every `keys` field removed at any depth (wall times differ run to run)."""
    if isinstance(value, dict):
        return {k: without(v, keys) for k, v in value.items() if k not in keys}
    if isinstance(value, list):
        return [without(v, keys) for v in value]
    return value
