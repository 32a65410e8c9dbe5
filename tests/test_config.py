"""Configs: typed from_dict with one-line errors, TOML record round trip, machine spec."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import pytest

from excavator_surrogate.config import dumps_toml, from_dict, to_dict
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.spec import EXCAVATOR, JointSpec, MachineSpec


@dataclass(frozen=True)
class Inner:
    a: int = 1
    """An int."""


@dataclass(frozen=True)
class Cfg:
    x: float = 1.0
    """A float."""
    names: tuple[str, ...] = ("a",)
    """Names."""
    opt: int | None = None
    """Optional."""
    inner: Inner = Inner()
    """Nested."""


def test_from_dict_types_and_errors() -> None:
    c = from_dict(Cfg, {"x": 2, "names": ["p", "q"], "inner": {"a": 3}})
    assert c == Cfg(x=2.0, names=("p", "q"), inner=Inner(a=3))
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['y'\]"):
        from_dict(Cfg, {"y": 1})
    with pytest.raises(ConfigError, match="cfg.x: expected a number"):
        from_dict(Cfg, {"x": "fast"}, where="cfg")


def test_toml_record_roundtrip() -> None:
    c = Cfg(x=0.5, names=("a", "b"), inner=Inner(a=4))
    text = dumps_toml({"name": "t", "stage": to_dict(c)})
    back = tomllib.loads(text)
    assert from_dict(Cfg, back["stage"]) == c


def test_spec_roundtrip_and_errors() -> None:
    assert MachineSpec.from_dict(EXCAVATOR.to_dict()) == EXCAVATOR
    assert EXCAVATOR.n_feature == 9 and EXCAVATOR.names[0] == "swing"
    with pytest.raises(ConfigError, match="unique"):
        MachineSpec(joints=(JointSpec("a"), JointSpec("a")))
    with pytest.raises(ConfigError, match="invalid"):
        JointSpec("Bad Name")


def test_atomic_outputs_respect_umask(tmp_path) -> None:
    import os

    from excavator_surrogate.io_utils import atomic_dir, write_text

    old = os.umask(0o022)
    try:
        write_text(tmp_path / "a.txt", "x")
        with atomic_dir(tmp_path / "d") as d:
            (d / "f").write_text("y")
        assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
        assert (tmp_path / "d").stat().st_mode & 0o777 == 0o755
    finally:
        os.umask(old)


@pytest.mark.parametrize("name", ["run", "simulate", "clean", "train", "evaluate", "sweep"])
def test_every_stage_config_has_from_preset(name: str) -> None:
    from excavator_surrogate.config import PresetConfig, load_preset, stage_config
    from excavator_surrogate.stages import stage_classes

    cls = stage_classes()[name]
    assert issubclass(cls, PresetConfig) and cls.preset_table == name
    preset = load_preset("paper-compound")  # sets keys of several tables, extends another
    expected = stage_config(cls, preset, name)
    assert cls.from_preset("paper-compound") == expected  # by name
    assert cls.from_preset(preset) == expected  # a loaded preset
    assert cls.from_preset({}) == cls()  # no table: the defaults
    field = next(iter(to_dict(cls())))
    value = getattr(expected, field)
    # an override replaces the preset's value; None keeps it
    assert getattr(cls.from_preset(preset, **{field: None}), field) == value
    with pytest.raises(ConfigError, match=rf"\[{name}\].*no_such_key"):
        cls.from_preset(preset, no_such_key=1)


def test_from_preset_reads_the_table_and_overrides() -> None:
    from excavator_surrogate.simulate import SimulateConfig
    from excavator_surrogate.training import TrainConfig

    assert SimulateConfig.from_preset("tiny").n_train == 2  # tiny.toml: n_train = 2
    assert SimulateConfig.from_preset("tiny", n_train=5).n_train == 5
    assert TrainConfig.from_preset("tiny", epochs=1).hidden == 16
    with pytest.raises(ConfigError, match="no-such-preset"):
        SimulateConfig.from_preset("no-such-preset")


def test_an_unknown_key_names_its_close_match() -> None:
    with pytest.raises(
        ConfigError, match=r"unknown key\(s\) \['nmes'\] for Cfg \(did you mean 'names'\?\)"
    ):
        from_dict(Cfg, {"nmes": ["b"]}, where="t")
