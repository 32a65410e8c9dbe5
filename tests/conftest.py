"""Shared test setup: single-threaded torch, headless matplotlib, deterministic seeds."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("MUJOCO_GL", "egl")

try:
    import torch

    torch.set_num_threads(1)
except ImportError:  # pragma: no cover
    pass


@pytest.fixture(autouse=True)
def _short_speed_probe(monkeypatch) -> None:
    """The dry runs' speed probe (``training/speed_probe.py``) in short bursts and short
    validation free runs: the tests check what it prints, not how well it times."""
    from excavator_surrogate.training import speed_probe

    monkeypatch.setattr(speed_probe, "PROBE_SECONDS", 0.02)
    monkeypatch.setattr(speed_probe, "PROBE_VAL_STEPS", 200)


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., tuple[int, str, str]]:
    """Run ``exsur`` in-process: ``cli("import", ...) -> (exit code, stdout, stderr)``."""
    from excavator_surrogate.cli import main

    def run(*argv: str | Path) -> tuple[int, str, str]:
        rc = main([str(a) for a in argv])
        cap = capsys.readouterr()
        return rc, cap.out, cap.err

    return run
