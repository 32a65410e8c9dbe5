"""Independent trainings side by side: the process path equals the in-process loop."""

from __future__ import annotations

import pytest
import torch

from excavator_surrogate.errors import ExsurError
from excavator_surrogate.surrogate.checkpoint import read_checkpoint
from excavator_surrogate.training import TrainJob, train_parallel
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
