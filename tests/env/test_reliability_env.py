"""Issue 17 in the environments: a checkpoint of another machine or rate, non-real actions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from excavator_surrogate.env.safety import ActionError
from excavator_surrogate.env.surrogate_env import ExcavatorSurrogateEnv
from excavator_surrogate.env.vector import SurrogateVectorEnv
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.spec import EXCAVATOR


@pytest.mark.parametrize("env_cls", [ExcavatorSurrogateEnv, SurrogateVectorEnv])
def test_env_refuses_a_checkpoint_of_another_rate_or_machine(env_cls, stateful_ckpt: Path) -> None:
    kw = {"n_envs": 2} if env_cls is SurrogateVectorEnv else {}
    with pytest.raises(CheckpointError, match=r"stateful.pt: .*rate 20 Hz vs 10 Hz"):
        env_cls(stateful_ckpt, spec=EXCAVATOR.with_rate(10.0), **kw)
    arm = EXCAVATOR.__class__(joints=EXCAVATOR.joints[1:], rate_hz=20.0, name="arm3")
    with pytest.raises(CheckpointError, match=r"joints \['swing', 'boom', 'arm', 'bucket'\] vs"):
        env_cls(stateful_ckpt, spec=arm, **kw)
    env = env_cls(stateful_ckpt, spec=EXCAVATOR, **kw)  # the right machine is accepted
    env.close()


@pytest.mark.parametrize(
    "action",
    [
        np.array([1 + 2j, 0, 0, 0]),
        np.array([1.0, 0, 0, 0], dtype=np.complex64),
        np.array(["1", "0", "0", "0"]),
        np.array([1j, 0, 0, 0], dtype=object),
    ],
)
def test_w7_non_real_actions_raise(action: np.ndarray, stateful_ckpt: Path) -> None:
    env = ExcavatorSurrogateEnv(stateful_ckpt)
    env.reset(seed=0)
    with pytest.raises(ActionError, match="ExcavatorSurrogate-v0: action"):
        env.step(action)
    obs, *_ = env.step(np.array([1, 0, 0, 0], dtype=np.int64))  # integers are real numbers
    assert np.isfinite(obs).all()
    env.close()


@pytest.mark.parametrize(
    ("commands", "msg"),
    [
        ("steps:seconds=inf", "seconds must be a finite number"),
        ("steps:seed=-3", "seed must be >= 0"),
    ],
)
def test_compare_bad_numbers_are_one_line(
    commands: str, msg: str, stateful_ckpt: Path, tmp_path: Path, capsys
) -> None:
    from excavator_surrogate.cli import main

    assert (
        main(["compare", str(stateful_ckpt), "--commands", commands, "--out", str(tmp_path / "C")])
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and msg in err and not (tmp_path / "C").exists()
