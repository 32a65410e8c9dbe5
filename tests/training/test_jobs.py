"""Independent trainings side by side: the process path equals the in-process loop, and a
capped pool of single networks shares one deadline."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from excavator_surrogate.errors import ExsurError
from excavator_surrogate.surrogate.checkpoint import read_checkpoint
from excavator_surrogate.training import TrainJob, train_parallel
from excavator_surrogate.training import jobs as jobs_module
from excavator_surrogate.training.ensembles import train_member
from excavator_surrogate.training.jobs import job_cap, run_jobs, with_deadlines
from tests.helpers.training import tiny_dataset, tiny_train_config


def _weights(path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path)["state_dict"]


def test_side_by_side_equals_one_after_the_other(tmp_path) -> None:
    ds = tiny_dataset(n_train=2, n_step=120)
    cfgs = [tiny_train_config(epochs=2, seed=s) for s in (0, 1)]

    def jobs(root):
        return [TrainJob(c, ds, root / f"m{i}", tag=f"job {i}") for i, c in enumerate(cfgs)]

    par = train_parallel(jobs(tmp_path / "par"), cpus=2)  # two spawned processes
    seq = train_parallel(jobs(tmp_path / "seq"), cpus=1)  # this process, one after the other
    assert [p.parent.name for p in par] == ["m0", "m1"]
    # Not bitwise: another process may pick other CPU kernels.  Rounding differences stay far
    # below the difference between the two seeds' networks, which a mixed-up job would show.
    w0, w1 = _weights(seq[0]), _weights(seq[1])
    seed_gap = min(float((w0[k] - w1[k]).abs().max()) for k in w0 if w0[k].is_floating_point())
    assert seed_gap > 0  # different seeds trained different networks
    for a, b in zip(par, seq):
        wa, wb = _weights(a), _weights(b)
        assert wa.keys() == wb.keys()
        for k in wa:
            torch.testing.assert_close(wa[k], wb[k], rtol=0, atol=1e-3 * seed_gap)


def test_a_user_error_in_a_worker_names_the_job(tmp_path) -> None:
    ds = tiny_dataset(n_train=1, n_step=30)  # shorter than seq_len: a DataError in the worker
    good = tiny_dataset(n_train=1, n_step=120)
    jobs = [
        TrainJob(tiny_train_config(epochs=1), good, tmp_path / "ok", tag="exsur lstm"),
        TrainJob(tiny_train_config(epochs=1), ds, tmp_path / "bad", tag="exsur lstm-raw"),
    ]
    with pytest.raises(ExsurError, match=r"^exsur lstm-raw: .*seq_len"):
        train_parallel(jobs, cpus=2)


def _job(tmp_path, name: str, *, cap: float, members: int = 1) -> TrainJob:
    cfg = tiny_train_config(epochs=1, max_train_seconds=cap, members=members)
    return TrainJob(cfg, tiny_dataset(n_train=1, n_step=60), tmp_path / name, tag=name)


def test_a_capped_pool_shares_one_deadline_of_its_rounds(tmp_path) -> None:
    jobs = [_job(tmp_path, f"m{i}", cap=100.0) for i in range(5)]
    got = with_deadlines(jobs, workers=2, now=1000.0)
    # 5 jobs on 2 workers: 3 rounds; the first round starts on time and keeps its caps
    assert [j.deadline for j in got] == [None, None] + [1300.0] * 3
    one = with_deadlines(jobs[:3], workers=1, now=1000.0)
    assert [j.deadline for j in one] == [None, 1300.0, 1300.0]  # one after the other
    # no cap, or a whole ensemble that plans its own rounds: no deadline
    free = with_deadlines([_job(tmp_path, "f", cap=0.0)], workers=2, now=1000.0)
    whole = with_deadlines([_job(tmp_path, "e", cap=100.0, members=4)], workers=2, now=1000.0)
    assert free[0].deadline is None and whole[0].deadline is None


def test_a_job_starting_late_gets_what_is_left_of_the_deadline() -> None:
    # cap' = max(0.1 cap, min(cap, deadline - now))
    assert job_cap(100.0, 1300.0, now=1000.0) == 100.0  # on time: its own cap
    assert job_cap(100.0, 1300.0, now=1230.0) == 70.0  # the last round, 30 s late
    assert job_cap(100.0, 1300.0, now=1400.0) == pytest.approx(10.0)  # past it: 10 %
    assert job_cap(100.0, None, now=5000.0) == 100.0
    assert job_cap(0.0, 1300.0, now=5000.0) == 0.0  # no cap stays none


def test_the_jobs_run_with_the_caps_left_at_their_start(tmp_path, monkeypatch) -> None:
    clock = iter([1000.0, 1180.0, 1260.0])  # the pool, then each later job's start
    monkeypatch.setattr(jobs_module, "wall_time", lambda: next(clock))
    caps: list[float] = []

    def fake(job: TrainJob, show_progress) -> Path:
        caps.append(job.cfg.max_train_seconds)
        return job.out / "best.pt"

    jobs = [_job(tmp_path, f"m{i}", cap=100.0) for i in range(3)]
    run_jobs(fake, jobs, workers=1)
    # deadline 1300: the second starts at 1180 (120 s left, more than its cap), the third at
    # 1260 (40 s left)
    assert caps == [100.0, 100.0, 40.0]
    assert jobs[2].cfg.max_train_seconds == 100.0  # the caller's jobs are left as they were


def test_a_later_round_in_a_worker_starts_with_the_deadline_left(tmp_path) -> None:
    # 3 single networks on 2 workers are 2 rounds of a 1-ms cap: the pool's deadline passes
    # while the first round starts its processes, so the third job gets the floor, 10 %
    ds = tiny_dataset(n_train=1, n_step=120)
    cfg = tiny_train_config(epochs=2, max_train_seconds=1e-3)
    jobs = [TrainJob(replace(cfg, seed=i), ds, tmp_path / f"m{i}", tag=f"m{i}") for i in range(3)]
    run_jobs(train_member, jobs, workers=2)
    caps = [
        tomllib.loads((tmp_path / f"m{i}" / "config.toml").read_text())["train"][
            "max_train_seconds"
        ]
        for i in range(3)
    ]
    assert caps[:2] == [1e-3, 1e-3]
    assert caps[2] == pytest.approx(1e-4)
