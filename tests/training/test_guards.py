"""Training guards: no excitation is refused or named, non-finite weights stop training,
out-of-range knobs are one-line config errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.training import TrainConfig, train
from excavator_surrogate.training.guards import check_excitation, check_finite
from tests.helpers.training import tiny_dataset, tiny_train_config


def _frozen(ds, joints):
    """``ds`` with the angles and commands of ``joints`` held at their first sample in every
    split (a constant signal)."""
    for eps in ds.episodes.values():
        for e in eps:
            for j in joints:
                e.theta[:, j] = e.theta[0, j]
                e.omega[:, j] = 0.0
                e.u[:, j] = e.u[0, j]
    return ds


def test_a_dataset_where_nothing_moves_is_refused_before_training(tmp_path):
    ds = _frozen(tiny_dataset(2, n_train=2, n_step=120), [0, 1])
    with pytest.raises(DataError, match=r"no joint's angle or command ever moves in the 'train'"):
        train(tiny_train_config(epochs=1), ds, out=tmp_path / "m")
    assert not (tmp_path / "m" / "best.pt").exists()


def test_a_still_joint_is_named_in_one_warning_line():
    ds = _frozen(tiny_dataset(3, n_train=2, n_step=120), [1])
    warnings = check_excitation(ds)
    name = ds.spec.names[1]
    assert len(warnings) == 1
    assert f"joint '{name}' angle and command never moves" in warnings[0]
    assert check_excitation(tiny_dataset(3, n_train=2, n_step=120)) == []


def test_check_finite_names_the_epoch_and_the_parameter():
    net = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    check_finite(net, epoch=3, lr=1e-3)  # finite: no error
    with torch.no_grad():
        net[1].bias[0] = float("nan")
    with pytest.raises(ConfigError) as e:
        check_finite(net, epoch=0, lr=1e308)
    msg = str(e.value)
    assert "non-finite at epoch 0 (1.bias)" in msg and "lr = 1e+308" in msg
    assert "lower train.lr" in msg and "\n" not in msg


def test_a_huge_lr_overflows_the_weights_and_check_finite_sees_it():
    """The case of the issue: one finite gradient times lr = 1e308 (the config refuses it now;
    the guard catches any other route, e.g. a learning-rate schedule)."""
    torch.manual_seed(0)
    net = torch.nn.Linear(3, 1)
    net(torch.ones(5, 3)).pow(2).sum().backward()
    with torch.no_grad():  # the optimiser's step p -= lr * grad, in float32
        for p in net.parameters():
            p.sub_(p.grad * 1e308)
    assert not all(bool(torch.isfinite(p).all()) for p in net.parameters())
    with pytest.raises(ConfigError, match="became non-finite at epoch 7"):
        check_finite(net, epoch=7)


@pytest.mark.parametrize(
    ("kw", "says"),
    [
        ({"seed": -5}, "seed = -5 must be >= 0"),
        ({"lr": 1e308}, "lr = 1e+308 must be in (0, 1]"),
        ({"lr": 0.0}, "lr = 0.0 must be in (0, 1]"),
        ({"max_train_seconds": -1.0}, "max_train_seconds = -1.0 must be >= 0"),
        ({"hidden": 100_000_000}, "[train] hidden = 100000000, layers = 2"),
    ],
)
def test_out_of_range_train_knobs_are_config_errors(kw, says):
    with pytest.raises(ConfigError) as e:
        TrainConfig(**kw)
    assert says in str(e.value)


def test_the_size_check_names_the_estimate_and_the_memory(monkeypatch):
    from excavator_surrogate.surrogate import sizes

    monkeypatch.setattr(sizes, "available_memory", lambda: 10_000_000)  # 10 MB
    TrainConfig(hidden=64, head_hidden=64)  # ~50k parameters x 16 B = 0.8 MB: fits
    with pytest.raises(ConfigError) as e:
        TrainConfig(hidden=1024)
    msg = str(e.value)
    assert "parameters x 16 B" in msg and "but 10 MB of memory is available" in msg
    assert np.isfinite(float(msg.split("needs about ")[1].split()[0]))


def test_training_stops_in_one_line_when_the_weights_turn_non_finite(tmp_path, monkeypatch):
    import excavator_surrogate.training.loop as loop_mod

    nets = []

    def spy(net, **kw):  # the loop's check, recording the net it watches
        nets.append(net)
        return check_finite(net, **kw)

    def corrupt(epoch, row):  # after epoch 0: one weight becomes NaN (as an overflow would)
        if epoch == 0:
            with torch.no_grad():
                next(nets[0].parameters()).view(-1)[0] = float("nan")
        return False

    monkeypatch.setattr(loop_mod, "check_finite", spy)
    with pytest.raises(ConfigError, match="epoch 1"):
        train(
            tiny_train_config(epochs=3),
            tiny_dataset(2, n_train=2, n_step=120),
            out=tmp_path / "m",
            on_epoch=corrupt,
            show_progress=False,
        )
