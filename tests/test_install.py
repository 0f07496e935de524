"""The package as users install it: a wheel built from this checkout, in a fresh virtualenv,
run from another folder (its configs and the paper's numbers must ship inside it)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_a_wheel_in_a_fresh_virtualenv_runs_and_renders_tables(tmp_path) -> None:
    source = tmp_path / "source"  # a copy: building writes build/ and *.egg-info beside the code
    shutil.copytree(ROOT, source, symlinks=True, ignore=shutil.ignore_patterns(
        ".venv", ".git", "results", "build", "*.egg-info", "__pycache__", ".*_cache"))  # fmt: skip
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "-w", str(tmp_path / "wheel"), str(source)],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = (tmp_path / "wheel").glob("edr-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    # The dependencies come from this environment (a path, not its .pth files: the editable
    # install of this checkout stays out of sight); edr itself only from the wheel.
    (Path(site) / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
         str(wheel)],
        check=True, capture_output=True,
    )  # fmt: skip
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = subprocess.run(
        [python, "-c", "import edr; print(edr.__file__)"], cwd=elsewhere, check=True,
        capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert where.startswith(site), where

    run = subprocess.run(
        [venv / "bin" / "edr-run", "task=kth", "debug=tiny"], cwd=elsewhere, capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    (record,) = (elsewhere / "results" / "runs" / "kth").glob("*/run.json")
    assert json.loads(record.read_text())["status"] == "finished"
    assert "kth finished: accuracy" in run.stdout + run.stderr

    tables = subprocess.run(
        [venv / "bin" / "edr-tables", "--runs", "results", "--out", "paper"], cwd=elsewhere, capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip
    assert tables.returncode == 0, tables.stderr[-3000:]
    table4 = (elsewhere / "paper" / "table4_kth.md").read_text()
    assert "## The paper's numbers" in table4 and "94.4" in table4  # found inside the package
    published = subprocess.run(
        [python, "-c", "from edr.report.published import load_published as p; "
         "print(p()['table4_kth']['accuracy']['nin_ftrcn']['edr'])"],
        cwd=elsewhere, check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert published.strip() == "94.4"  # the paper's NiN + FT-RCN with EDR, found when installed
