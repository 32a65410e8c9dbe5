"""Same data, same seed, same model: the amount of training is planned, the wall clock only caps it."""

from __future__ import annotations

import hashlib
import itertools
import subprocess
import sys
from pathlib import Path

import pytest

from excavator_surrogate import numerics
from excavator_surrogate.surrogate import read_checkpoint
from excavator_surrogate.training import train
from excavator_surrogate.training.config import TrainConfig
from excavator_surrogate.training.optim import cosine_lr
from tests.helpers.training import tiny_dataset, tiny_train_config


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class _Burner:
    """Processes that keep every core busy while the block runs (a busy computer)."""

    def __init__(self, n: int = 2) -> None:
        self.n = n
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> _Burner:
        code = "import time\nt = time.monotonic()\nwhile time.monotonic() - t < 600: pass\n"
        self.procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(self.n)]
        return self

    def __exit__(self, *exc: object) -> None:
        for p in self.procs:
            p.kill()
            p.wait()


@pytest.mark.parametrize("members", [1, 2])
def test_same_seed_gives_a_bit_identical_best_pt_on_an_idle_and_a_busy_machine(tmp_path, members):
    # free-run feedback, EMA weights, a cosine schedule, a generous cap: every part of the
    # recipe that used to read the clock
    cfg = tiny_train_config(
        epochs=3,
        feedback="free",
        teacher_epochs=1,
        ema_decay=0.9,
        lr_schedule="cosine",
        members=members,
        max_train_seconds=600.0,
    )
    ds = tiny_dataset(2, n_train=2, n_step=120)
    train(cfg, ds, out=tmp_path / "idle", show_progress=False)
    with _Burner():
        train(cfg, ds, out=tmp_path / "busy", show_progress=False)
    idle, busy = tmp_path / "idle" / "best.pt", tmp_path / "busy" / "best.pt"
    assert _sha(idle) == _sha(busy)
    ck = read_checkpoint(idle)
    assert ck["metrics"]["training"]["budget_cut"] is False
    assert all("time_s" not in row for row in ck["history"])


def test_a_wall_time_cap_that_cuts_training_says_so(tmp_path, caplog):
    cfg = tiny_train_config(epochs=50, max_train_seconds=1e-3)
    train(cfg, tiny_dataset(2, n_train=2, n_step=120), out=tmp_path / "c", show_progress=False)
    training = read_checkpoint(tmp_path / "c" / "best.pt")["metrics"]["training"]
    assert training["budget_cut"] is True and training["stopped"] == "budget"
    assert (training["epochs_done"], training["epochs_planned"]) == (1, 50)
    err = caplog.text  # a warning of the package logger
    assert "stopped training after 1 of 50 planned epochs" in err and "--max-seconds" in err


def test_a_run_that_completes_its_plan_is_not_cut(tmp_path):
    cfg = tiny_train_config(epochs=2, patience=5)
    train(cfg, tiny_dataset(2, n_train=2, n_step=120), out=tmp_path / "d", show_progress=False)
    training = read_checkpoint(tmp_path / "d" / "best.pt")["metrics"]["training"]
    assert training.pop("environment") == numerics.environment()  # the computer it ran on
    assert training == {
        "epochs_planned": 2,
        "epochs_done": 2,
        "stopped": "planned",
        "budget_cut": False,
        "max_train_seconds": 0.0,
        "numerics": "native",
    }


def test_the_cosine_schedule_follows_the_epochs_only():
    cfg = TrainConfig(lr=1e-3, min_lr=1e-5, epochs=10, lr_schedule="cosine", max_train_seconds=1.0)
    lrs = [cosine_lr(cfg, e)() for e in range(10)]
    assert lrs[0] == pytest.approx(1e-3)
    assert lrs[5] == pytest.approx(1e-5 + 0.5 * (1e-3 - 1e-5))
    assert all(a > b for a, b in itertools.pairwise(lrs))
    assert cosine_lr(TrainConfig(lr_schedule="plateau"), 3)() is None
