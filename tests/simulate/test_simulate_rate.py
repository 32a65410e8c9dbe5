"""A ``[simulate]`` rate the simulator cannot sample at is refused up front, in one line that
names the value and where it came from and says which rates work; an episode the simulation
makes that still breaks the contract is reported without a temporary path or import advice."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from excavator_surrogate.data import plausible
from excavator_surrogate.errors import ConfigError, DataError
from excavator_surrogate.simulate.config import MIN_RATE_HZ, SimulateConfig, packaged_timestep
from excavator_surrogate.simulate.generate import simulate_dataset, simulated_data_error

CLI = Callable[..., tuple[int, str, str]]


def _no_temp_or_import(text: str) -> None:
    assert ".tmp" not in text and "import" not in text, text


@pytest.mark.parametrize(
    ("rate", "why"),
    [
        (0.01, "samples every 100 s, too slowly"),
        (0.5, "samples every 2 s, too slowly"),
        (0.0, "is not a sample rate"),
        (-5.0, "is not a sample rate"),
        (3.0, "sample period of 0.333333 s, not a whole number of the packaged excavator's 2 ms"),
        (1000.0, "sample period of 0.001 s, not a whole number"),
    ],
)
def test_a_rate_the_simulator_cannot_sample_is_refused(rate: float, why: str) -> None:
    with pytest.raises(ConfigError) as err:
        SimulateConfig(rate_hz=rate)
    msg = str(err.value)
    assert msg.startswith(f"simulate.rate_hz = {rate:g} Hz ") and why in msg
    assert "use 500 Hz / n from 1 to 500 Hz (e.g. 10, 20, 50, 100 Hz)" in msg
    _no_temp_or_import(msg)


@pytest.mark.parametrize("rate", [MIN_RATE_HZ, 2.0, 10.0, 20.0, 50.0, 125.0, 500.0])
def test_the_rates_the_error_suggests_work(rate: float) -> None:
    assert packaged_timestep() == pytest.approx(0.002)
    assert SimulateConfig(rate_hz=rate).plant_config().rate_hz == rate


def test_a_custom_mjcf_has_its_timestep_checked_by_its_plant(tmp_path: Path) -> None:
    """The packaged timestep says nothing of another MJCF: 7 Hz passes the config and the
    plant (loaded in the parent before any episode) refuses it, naming the rate."""
    from excavator_surrogate.simulate.plant import default_xml

    xml = tmp_path / "mine.xml"
    xml.write_text(default_xml().read_text())
    cfg = SimulateConfig(rate_hz=7.0, xml=str(xml), n_train=1, n_val=0, n_test=0)
    with pytest.raises(ConfigError, match=r"rate_hz = 7 Hz samples every 0.142857 s.*500 Hz / n"):
        simulate_dataset(cfg, out=tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(ConfigError, match="too slowly"):
        SimulateConfig(rate_hz=0.01, xml=str(xml))


def test_a_negative_delay_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"simulate.delay_s = -1 must be >= 0 \[s\]"):
        SimulateConfig(delay_s=-1.0)


def test_cli_set_rate_is_one_line_before_anything_is_simulated(tmp_path: Path, cli: CLI) -> None:
    out = tmp_path / "rx"
    rc, _, err = cli("simulate", "--preset", "tiny", "--out", out, "--set", "simulate.rate_hz=0.01")
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0] == (
        "exsur: error: simulate.rate_hz = 0.01 Hz samples every 100 s, too slowly for the "
        "excavator's moves (a full stroke takes 3-4 s); use 500 Hz / n from 1 to 500 Hz "
        "(e.g. 10, 20, 50, 100 Hz) (simulate.rate_hz: from --set or a flag)"
    )
    assert list(tmp_path.iterdir()) == []  # no output, no temporary folder


def test_cli_preset_rate_names_the_preset_file(tmp_path: Path, cli: CLI) -> None:
    preset = tmp_path / "slow.toml"
    preset.write_text('extends = "tiny"\n[simulate]\nrate_hz = 3\n')
    for command in ("simulate", "run"):
        rc, _, err = cli(command, "--preset", preset, "--out", tmp_path / "rx")
        assert rc == 2
        assert "simulate.rate_hz = 3 Hz has a sample period of 0.333333 s" in err
        assert err.strip().endswith(f"(simulate.rate_hz: from {preset})"), err
        _no_temp_or_import(err)
    assert not (tmp_path / "rx").exists()


def test_an_implausible_simulated_episode_names_the_episode_and_the_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Should a simulation still make data the episode contract refuses, the error names the
    episode and the [simulate] settings, not the temporary file or the import's advice."""
    monkeypatch.setattr(plausible, "MAX_TURNS", 1e-9)  # any motion is now "impossible"
    cfg = SimulateConfig(n_train=1, n_val=0, n_test=0, steps_train=20)
    with pytest.raises(DataError) as err:
        simulate_dataset(cfg, out=tmp_path / "rx")
    msg = str(err.value)
    assert msg.startswith("simulated episode 'train_000', column '"), msg
    assert "the [simulate] settings (rate_hz = 20 Hz, plant = 'ideal')" in msg
    _no_temp_or_import(msg)
    assert not (tmp_path / "rx").exists()


def test_simulated_data_error_passes_other_errors_through() -> None:
    cfg = SimulateConfig()
    other = DataError("out", "duplicate episode name 'a'", fix="give episodes unique names")
    assert simulated_data_error(other, cfg) is other
    tmp = DataError(
        Path(".rx.1-abc.tmp/episodes/val_003.parquet"), "bad", column="omega_arm", row=4
    )
    msg = str(simulated_data_error(tmp, cfg))
    assert msg.startswith("simulated episode 'val_003', column 'omega_arm', row 4: bad (")
    _no_temp_or_import(msg)
