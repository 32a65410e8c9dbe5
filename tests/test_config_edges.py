"""Edge cases of the config layer: every branch of from_dict's typing, load_preset's file errors,
--set conflicts, the machine spec's rules and the stage configs' own range checks."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from excavator_surrogate.clean.config import CleanConfig
from excavator_surrogate.config import from_dict, load_preset, parse_sets, to_dict
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.simulate.config import SimulateConfig
from excavator_surrogate.spec import InputSpec, JointSpec, MachineSpec


@dataclass(frozen=True)
class Inner:
    a: int = 1
    """An int."""


@dataclass(frozen=True)
class Edge:
    anything: Any = None
    """Any value."""
    where: Path = Path("x")
    """A type from_dict does not check."""
    pair: tuple[float, float] = (0.0, 1.0)
    """Two numbers."""
    table: dict[str, Any] = field(default_factory=dict)
    """A free table."""
    inner: Inner = Inner()
    """Nested."""
    name: str = "a"
    """A string."""
    opt: float | None = 1.0
    """Optional."""


def test_from_dict_accepts_any_none_tables_and_config_objects() -> None:
    e = from_dict(Edge, {"anything": [1, "x"], "opt": None, "table": {"k": 1}, "inner": Inner(2)})
    assert e.anything == [1, "x"] and e.opt is None and e.table == {"k": 1} and e.inner.a == 2
    assert from_dict(Edge, {"where": "p"}).where == "p"  # unchecked types pass as they are


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"pair": 3}, "cfg.pair: expected a list, got 3"),
        ({"pair": [1, 2, 3]}, "cfg.pair: expected 2 values, got 3"),
        ({"table": 5}, "cfg.table: expected a table, got 5"),
        ({"inner": 3}, "cfg.inner: expected a table, got 3"),
        ({"name": 5}, "cfg.name: expected a string, got 5"),
        ({"opt": "x"}, "cfg.opt: expected a number, got 'x'"),
    ],
)
def test_from_dict_names_the_key_of_a_value_of_the_wrong_shape(data: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        from_dict(Edge, data, where="cfg")
    assert str(e.value) == message


def test_to_dict_writes_paths_as_text() -> None:
    assert to_dict(Edge(where=Path("a/b")))["where"] == "a/b"


def test_a_missing_or_broken_preset_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"missing\.toml: preset file not found \(give a shipped"):
        load_preset(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[train\nepochs = 1\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: invalid TOML \(.*line 1"):
        load_preset(bad)


def test_a_set_below_a_value_set_before_is_refused() -> None:
    with pytest.raises(ConfigError) as e:
        parse_sets(["train.lr=1", "train.lr.x=2"])
    msg = str(e.value)
    assert msg.startswith("--set 'train.lr.x=2': an earlier --set gave train.lr a value")
    assert "keep one of the two" in msg and "\n" not in msg


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"omega_max": 0.0}, "joint 'a': omega_max (0.0) must be positive or None"),
        ({"u_min": 1.0, "u_max": 1.0}, "joint 'a': u_max (1.0) must exceed u_min (1.0)"),
        ({"theta_min": math.inf}, "joint 'a': theta_min must be a finite number, got inf"),
        ({"u_min": math.nan}, "joint 'a': u_min must be a finite number, got nan"),
        ({"omega_max": math.nan}, "joint 'a': omega_max must be a finite number, got nan"),
        (
            {"theta_min": 1.0, "theta_max": -1.0},
            "joint 'a': theta_max (-1) is below theta_min (1); give the limits as [lower, upper]",
        ),
    ],
)
def test_joint_ranges(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        JointSpec("a", **kwargs)
    assert str(e.value) == message


def test_equal_limits_are_a_joint_that_does_not_move() -> None:
    assert JointSpec("a", theta_min=0.5, theta_max=0.5).theta_max == 0.5


def test_an_input_follows_a_joint_commands_rules_under_its_own_name() -> None:
    with pytest.raises(ConfigError, match="^input name 'Gas' is invalid"):
        InputSpec("Gas")
    with pytest.raises(ConfigError, match=r"^input 'gas': u_max \(0.0\) must exceed u_min"):
        InputSpec("gas", u_min=1.0, u_max=0.0)


def test_machine_rules() -> None:
    with pytest.raises(ConfigError, match="at least one joint"):
        MachineSpec(joints=())
    for rate in (0.0, math.inf):
        with pytest.raises(
            ConfigError, match=f"rate_hz must be a positive finite number, got {rate}"
        ):
            MachineSpec(joints=(JointSpec("a"),), rate_hz=rate)


def test_mismatch_names_command_ranges_and_inputs() -> None:
    m = MachineSpec(joints=(JointSpec("a"),))
    wide = MachineSpec(joints=(JointSpec("a", u_min=-2000.0),))
    assert m.mismatch(wide) == "joint 'a' command range [-1000, 1000] vs [-2000, 1000]"
    gas = MachineSpec(joints=(JointSpec("a"),), inputs=(InputSpec("gas"),))
    assert m.mismatch(gas) == "exogenous inputs [] vs [('gas', 0.0, 1.0)]"
    assert gas.mismatch(gas) is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"jump_ref": "next"}, "clean.jump_ref: must be 'raw' or 'prior', got 'next'"),
        ({"cons_mode": "all"}, "clean.cons_mode: must be 'anchors' or 'samples', got 'all'"),
        ({"tau_cons": 0.0}, "clean.tau_cons: must be positive, got 0.0"),
        ({"q_bias": -1.0}, "clean.q_bias: must be >= 0, got -1.0"),
        ({"p0_bias": 0.0}, "clean.p0_bias: must be positive, got 0.0"),
        # configs whose filter divides by zero (gyro3's gyro-row innovation, the RTS prior's
        # inverse): the loop engine raised ZeroDivisionError, the vector one returned NaN
        (
            {"method": "gyro3", "r_gyro": 0.0},
            "clean.r_gyro: must be positive for method 'gyro3' (the gyro is a measurement "
            "there), got 0.0",
        ),
        (
            {"method": "rts", "q_bias": 0.0},
            "clean: method 'rts' needs a positive definite process noise (q_bias > 0, and "
            "q_theta or r_gyro > 0), got q_bias=0.0, q_theta=1e-06, r_gyro=2.5e-05",
        ),
        (
            {"q_theta": 0.0, "r_gyro": 0.0},
            "clean: method 'rts' needs a positive definite process noise (q_bias > 0, and "
            "q_theta or r_gyro > 0), got q_bias=1e-07, q_theta=0.0, r_gyro=0.0",
        ),
    ],
)
def test_clean_config_ranges(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        CleanConfig(**kwargs)
    assert str(e.value) == message


def test_degenerate_noise_is_fine_where_nothing_divides_by_it() -> None:
    CleanConfig(method="paper", q_bias=0.0, r_gyro=0.0, q_theta=0.0)
    CleanConfig(method="gyro", q_bias=0.0, r_gyro=0.0)
    CleanConfig(method="rts", q_theta=0.0)


def test_clean_config_ranges_from_a_preset_table() -> None:
    with pytest.raises(ConfigError, match="clean.p0_omega: must be positive, got -1.0"):
        CleanConfig.from_preset({"clean": {"p0_omega": -1.0}})


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": -1}, "simulate.seed must be >= 0, got -1"),
        ({"n_val": -1}, "simulate.n_val must be >= 0, got -1"),
        ({"steps_test": 1}, "simulate.steps_test must be >= 2, got 1"),
        ({"val_signals": ()}, "simulate.val_signals must list at least one signal kind"),
        ({"n_train": 0, "n_val": 0, "n_test": 0}, "n_train + n_val + n_test is 0"),
        ({"workers": 0}, "simulate.workers must be >= 1, got 0"),
        ({"pose_margin": 0.5}, "simulate.pose_margin must be in [0, 0.5), got 0.5"),
    ],
)
def test_simulate_config_ranges(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError) as e:
        SimulateConfig(**kwargs)
    assert message in str(e.value)


def test_a_simulation_too_big_is_refused_and_a_long_one_announced(tmp_path, caplog) -> None:
    """``steps_train`` with an extra zero or three: refused before anything runs when it
    cannot fit, announced with its size and time when it only takes long."""
    import dataclasses
    import logging

    from excavator_surrogate.simulate.config import SimulateConfig
    from excavator_surrogate.stages import check_dataset_size

    base = SimulateConfig(n_train=2, n_val=1, n_test=1, steps_train=200, workers=1)
    with caplog.at_level(logging.WARNING, logger="excavator_surrogate.stages"):
        check_dataset_size(base, out=tmp_path / "d")
    assert not caplog.records  # a small one says nothing
    huge = dataclasses.replace(base, steps_train=10**12)
    with pytest.raises(ConfigError, match=r"2e\+12 samples .* lower simulate.n_train"):
        check_dataset_size(huge, out=tmp_path / "d")
    long = dataclasses.replace(base, steps_train=10**7)  # 20M samples: ~1.1 h, 2 GB
    with caplog.at_level(logging.WARNING, logger="excavator_surrogate.stages"):
        check_dataset_size(long, out=tmp_path / "d")
    assert "take ~1.11 h on 1 worker(s)" in caplog.text and "interrupt (Ctrl-C" in caplog.text
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("build", "line"),
    [
        (lambda: _train(epochs="3"), r"\[train\]\.epochs: expected an integer, got '3'"),
        (lambda: _train(lr="fast"), r"\[train\]\.lr: expected a number, got 'fast'"),
        (lambda: SimulateConfig(n_train="x"), r"\[simulate\]\.n_train: expected an integer"),
        (lambda: _mppi(n_sample="8"), r"mppi\.n_sample: expected an integer, got '8'"),
        (lambda: _evaluate(num_threads="2"), r"\[evaluate\]\.num_threads: expected an integer"),
        (lambda: _clean(tau_jump="0.1"), r"\[clean\]\.tau_jump: expected a number, got '0.1'"),
        (lambda: _clean(cons_window=2.5), r"\[clean\]\.cons_window: expected an integer"),
        (lambda: _sweep(epochs="3"), r"\[sweep\]\.epochs: expected an integer, got '3'"),
        (lambda: _sweep(window=(1, "4")), r"\[sweep\]\.window: expected an integer, got '4'"),
    ],
    ids=[
        *("train-epochs", "train-lr", "simulate", "mppi", "evaluate"),
        *("clean", "clean-int", "sweep", "sweep-range"),
    ],
)
def test_a_config_built_directly_refuses_a_wrong_type_in_one_line(build, line: str) -> None:
    with pytest.raises(ConfigError, match=line):
        build()


def test_numpy_scalars_and_value_checks_are_left_as_they_were() -> None:
    import numpy as np

    assert _train(epochs=np.int64(3)).epochs == 3
    with pytest.raises(ConfigError, match=r"lr = nan must be in \(0, 1\]"):
        _train(lr=math.nan)


def _train(**kw: Any):
    from excavator_surrogate.training.config import TrainConfig

    return TrainConfig(**kw)


def _mppi(**kw: Any):
    from excavator_surrogate.control.mppi import MPPIConfig

    return MPPIConfig(**kw)


def _clean(**kw: Any):
    from excavator_surrogate.clean.config import CleanConfig

    return CleanConfig(**kw)


def _sweep(**kw: Any):
    from excavator_surrogate.scale.sweep import SweepConfig

    return SweepConfig(**kw)


def _evaluate(**kw: Any):
    from excavator_surrogate.evaluate.cbe import EvaluateConfig

    return EvaluateConfig(**kw)
