"""The type information a user's checker reads is true: the stubs match the
native module (mypy's stubtest), and the package passes ``mypy --strict``."""

import pathlib
import subprocess
import sys

import pytest

import ndr

# scripts/test installs mypy; a run without it is a setup error, not a pass.
pytest.importorskip("mypy", reason="mypy is installed by scripts/test")

PACKAGE = pathlib.Path(ndr.__file__).parent


def _mypy(*args: str, cwd: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", *args],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
    )


@pytest.fixture
def empty_dir(tmp_path):
    # Run from here so that `ndr` is the installed package, with no
    # configuration but the command line's.
    (tmp_path / "mypy.ini").write_text("[mypy]\n", encoding="utf-8")
    return tmp_path


def test_the_stubs_match_the_native_module(empty_dir):
    proc = _mypy("mypy.stubtest", "ndr._native", "--mypy-config-file", "mypy.ini", cwd=empty_dir)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_the_installed_package_is_strictly_typed(empty_dir):
    proc = _mypy("mypy", "--strict", "--no-incremental", "-p", "ndr", cwd=empty_dir)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # Every module of the package was checked, not an empty set.
    modules = len(list(PACKAGE.glob("*.py"))) + len(list(PACKAGE.glob("*.pyi")))
    assert f"no issues found in {modules} source files" in proc.stdout, proc.stdout
