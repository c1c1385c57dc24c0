"""CI's workflow checks, inside the suite so that the README's test command runs them:
``snakefmt --check`` on every workflow file and ``snakemake --lint``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
WORKFLOW_FILES = [REPO / "Snakefile", *sorted((REPO / "workflow" / "rules").glob("*.smk"))]


def test_workflow_files_are_snakefmt_formatted() -> None:
    assert len(WORKFLOW_FILES) >= 8
    proc = subprocess.run([sys.executable, "-m", "snakefmt", "--check", "--diff", *map(str, WORKFLOW_FILES)],
                          capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 0, f"run `./run snakefmt Snakefile workflow/`:\n{proc.stdout[-4000:]}{proc.stderr[-2000:]}"


def test_snakemake_lint_finds_nothing() -> None:
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "--cores", "1"],
                          capture_output=True, text=True, cwd=REPO)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Lints for" not in out, out[-6000:]
