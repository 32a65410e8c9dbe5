"""Issue 25 probe: ``exsur simulate --workers 1000000`` starts one process per episode at most,
and its log line now says so (it said ``1000000 worker(s)``)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import ClassVar

import pytest

from excavator_surrogate.simulate import generate


class _Pool:
    """Stands in for the spawn pool: records its size, runs the jobs inline one by one (no
    processes or threads in a unit test; the MuJoCo rollouts are not run concurrently)."""

    sizes: ClassVar[list[int]] = []

    def __init__(self, max_workers: int, mp_context=None, initializer=None, initargs=()) -> None:
        _Pool.sizes.append(max_workers)

    def __enter__(self) -> _Pool:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def map(self, fn, items):
        return map(fn, items)


def test_the_log_names_the_workers_that_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    pytest.importorskip("mujoco")
    monkeypatch.setattr(generate, "ProcessPoolExecutor", _Pool)
    cfg = generate.SimulateConfig.from_preset("tiny")
    n_episode = len(generate.plan_episodes(cfg))
    with caplog.at_level(logging.INFO, logger="excavator_surrogate"):
        generate.simulate_dataset(cfg, out=tmp_path / "d", workers=1_000_000)
    assert _Pool.sizes == [n_episode]
    assert f"{n_episode} worker(s)" in caplog.text
    assert "1000000 worker(s)" not in caplog.text
