"""Static checks that CI enforces: Python 3.8 compatibility (our users' Noetic robots) and lint."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

PY38 = ["--target=3.8-", "--violations", "--no-tips", "--eval-annotations", "--feature", "union-types",
        "--backport", "typing_extensions", "--format", "parsable"]


def python_sources(root: Path):
    """Every Python file of the workspace: modules, tests, benchmarks and extension-less nodes
    (the skipped folders are never entered: the venv alone holds a hundred thousand files)."""
    skip = {".venv", "build", "devel", "node_modules", ".git", "artifacts"}
    files = []
    for folder, subfolders, names in os.walk(root):
        subfolders[:] = [name for name in subfolders if name not in skip]
        files += [Path(folder) / name for name in names]
    for path in sorted(files):
        if not path.is_file():
            continue
        if path.suffix == ".py":
            yield path
        elif not path.suffix and path.parent.name in ("nodes", "scripts"):
            with open(path, "rb") as handle:
                if b"python" in handle.readline():
                    yield path


def run_vermin(paths):
    vermin = Path(sys.executable).parent / "vermin"
    return subprocess.run([str(vermin), *PY38, *map(str, paths)], capture_output=True, text=True)


def test_every_python_file_runs_on_python_3_8(workspace_root):
    sources = list(python_sources(workspace_root))
    assert any(p.parent.name == "nodes" for p in sources) and len(sources) > 10
    result = run_vermin(sources)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


@pytest.mark.parametrize("snippet, feature", [
    ("match 3:\n    case 3:\n        pass\n", "pattern matching"),
    ("def f(x: int | None): ...\n", "union types as `X | Y`"),
    ("'abc'.removeprefix('a')\n", "str.removeprefix"),
    ("import tomllib\n", "tomllib"),
])
def test_the_python_3_8_check_catches_newer_features(tmp_path, snippet, feature):
    source = tmp_path / "new.py"
    source.write_text(snippet)
    result = run_vermin([source])
    assert result.returncode != 0 and feature in result.stdout, result.stdout + result.stderr


def test_ruff_finds_no_errors(workspace_root):
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--quiet", "."],
                            cwd=workspace_root, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
