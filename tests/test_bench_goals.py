"""bench/: every benchmark script ends with one JSON line holding a ``goals`` object of booleans.

The quick ones run here at a toy size: the structure is tested, never a timing (a goal may
be false at this size or under load; that is the benchmark's business, not the suite's).
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"

SMALL: dict[str, list[str]] = {
    "import.py": ["--rows", "20000"],
    "info.py": ["--seconds", "20", "--rate", "50", "--camera-hz", "10", "--cap", "100"],
    "simulate.py": ["--batch", "2", "--steps", "20", "--loop-episodes", "1"],
    "ensemble.py": ["--seconds", "0.01"],
    "clean.py": ["--episodes", "2", "--steps", "400", "--slice", "200", "--long-steps", "400"],
    "env.py": ["--threads", "1", "--seconds", "0.01", "--repeats", "1", "--reset-repeats", "3"],
    "cli.py": ["--repeats", "1"],
}
"""Scripts cheap enough to run in the suite, with arguments that make them tiny."""


def _scripts() -> list[Path]:
    """The runnable scripts of bench/ (those with a ``__main__`` block; not their helpers)."""
    return sorted(p for p in BENCH.glob("*.py") if '__name__ == "__main__"' in p.read_text())


def _has_goals_key(path: Path) -> bool:
    """Whether the script's source builds a ``"goals"`` entry (a dict key or a subscript)."""
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            if any(isinstance(k, ast.Constant) and k.value == "goals" for k in node.keys):
                return True
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            if node.slice.value == "goals":
                return True
    return False


def test_the_scripts_are_found() -> None:
    names = {p.name for p in _scripts()}
    assert set(SMALL) <= names
    assert "real.py" in names and "real_scores.py" not in names


@pytest.mark.parametrize("path", _scripts(), ids=lambda p: p.name)
def test_every_benchmark_reports_goals(path: Path) -> None:
    assert _has_goals_key(path), f"{path.name} ends without a goals object"


@pytest.mark.parametrize("name", sorted(SMALL))
def test_a_quick_benchmark_ends_with_json_goals_of_booleans(name: str) -> None:
    env = {**os.environ, "EXSUR_PROGRESS": "0", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, str(BENCH / name), *SMALL[name]],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    goals = last["goals"]
    assert isinstance(goals, dict) and goals
    assert all(v is None or isinstance(v, bool) for v in goals.values()), goals
