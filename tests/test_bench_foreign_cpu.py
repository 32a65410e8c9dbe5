"""bench/foreign_cpu.py: other processes' CPU time over a run, from /proc/stat less our own."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "bench" / "foreign_cpu.py"
_spec = importlib.util.spec_from_file_location("foreign_cpu", _PATH)
assert _spec is not None and _spec.loader is not None
foreign_cpu = importlib.util.module_from_spec(_spec)
sys.modules["foreign_cpu"] = foreign_cpu
_spec.loader.exec_module(foreign_cpu)


def _stat(tmp_path: Path, ticks: list[int]) -> Path:
    p = tmp_path / "stat"
    p.write_text("cpu  " + " ".join(map(str, ticks)) + "\ncpu0 1 2 3 4\nintr 0\n")
    return p


def test_busy_time_counts_every_state_but_idle_and_iowait(tmp_path: Path) -> None:
    hz = os.sysconf("SC_CLK_TCK")
    # user nice system idle iowait irq softirq steal guest guest_nice
    p = _stat(tmp_path, [100, 20, 30, 9000, 500, 5, 6, 7, 40, 0])
    assert foreign_cpu.busy_cpu_seconds(p) == pytest.approx((100 + 20 + 30 + 5 + 6 + 7) / hz)


def test_busy_time_is_none_without_a_readable_cpu_line(tmp_path: Path) -> None:
    assert foreign_cpu.busy_cpu_seconds(tmp_path / "missing") is None
    bad = tmp_path / "bad"
    bad.write_text("intr 0\n")
    assert foreign_cpu.busy_cpu_seconds(bad) is None


def test_share_subtracts_our_own_and_our_childrens_time(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = iter([100.0, 110.0])  # a 10-s run
    busy = iter([50.0, 69.0])  # the machine: 19 CPU-s busy
    own = iter([3.0, 20.0])  # ours and our members': 17 CPU-s
    monkeypatch.setattr(foreign_cpu.time, "monotonic", lambda: next(clock))
    monkeypatch.setattr(foreign_cpu, "busy_cpu_seconds", lambda: next(busy))
    monkeypatch.setattr(foreign_cpu, "own_cpu_seconds", lambda: next(own))
    share = foreign_cpu.ForeignCpu.start().share()
    assert share == pytest.approx(0.2)  # 2 CPU-s of others over 10 s
    assert share > foreign_cpu.BUSY_SHARE


def test_share_is_none_where_the_machine_cannot_be_read(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(foreign_cpu, "busy_cpu_seconds", lambda: None)
    assert foreign_cpu.ForeignCpu.start().share() is None


def test_share_never_goes_below_zero(monkeypatch: pytest.MonkeyPatch) -> None:
    busy = iter([10.0, 10.5])  # tick rounding: the machine's count lags our own
    own = iter([0.0, 1.0])
    monkeypatch.setattr(foreign_cpu, "busy_cpu_seconds", lambda: next(busy))
    monkeypatch.setattr(foreign_cpu, "own_cpu_seconds", lambda: next(own))
    assert foreign_cpu.ForeignCpu.start().share() == 0.0
