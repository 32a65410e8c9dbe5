"""The ``[simulate]`` table: :class:`SimulateConfig` (what ``exsur simulate`` generates,
:func:`~.generate.simulate_dataset` reads it), with the plants and the exogenous inputs a
simulation can record."""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

from .. import config as config_mod
from ..errors import ConfigError
from ..spec import InputSpec
from .excitation import CLOSED_LOOP, SIGNALS, ExcitationConfig
from .hydraulics import HydraulicConfig
from .plant import PlantConfig, rate_fits
from .sensors import SensorConfig
from .soil import SoilConfig

SOURCES: dict[str, str] = {"ideal": "mujoco-ideal", "hydraulic": "mujoco-hydraulic"}
"""``source`` metadata per plant kind."""
INPUTS: dict[str, InputSpec] = {
    "throttle": InputSpec("throttle", u_min=0.0, u_max=1.0, unit="fraction of full throttle")
}
"""Exogenous inputs a simulation can record (``SimulateConfig.inputs``)."""
MIN_RATE_HZ = 1.0
"""Slowest sample rate a simulation takes [Hz]: the packaged joints cross their range in 3-4 s
at full command and the excitation moves faster (multisine up to 1 Hz, PRBS holds from
0.3 s), so a sample period beyond 1 s skips whole moves (docs/plant.md); far slower, the swing
turns more than 10 times between two samples, which the episode contract refuses."""
RATE_EXAMPLES = (10.0, 20.0, 50.0, 100.0)
"""Sample rates an error suggests (the presets use 10 and 20 Hz)."""


@functools.cache
def packaged_timestep() -> float | None:
    """The physics timestep [s] of the packaged MJCF (``<option timestep>``, MuJoCo's default
    0.002 s without it), read without loading MuJoCo; None if the file cannot be read."""
    from .plant import default_xml

    try:
        option = ET.parse(default_xml()).getroot().find("option")
    except (OSError, ET.ParseError):
        return None
    try:
        return float(option.get("timestep", "0.002")) if option is not None else 0.002
    except ValueError:
        return None


@dataclass(frozen=True)
class SimulateConfig(config_mod.PresetConfig, table="simulate"):
    """What ``exsur simulate`` generates (TOML table ``[simulate]``)."""

    n_train: int = 12
    """Training episodes."""
    n_val: int = 2
    """Validation episodes (model selection; not in the paper)."""
    n_test: int = 1
    """Test episodes (unseen signal kind in the paper: steps)."""
    steps_train: int = 5300
    """Samples per training episode (at rate_hz)."""
    steps_val: int = 5300
    """Samples per validation episode."""
    steps_test: int = 1800
    """Samples per test episode."""
    train_signals: tuple[str, ...] = ("multisine",)
    """Signal kinds of training episodes, used in turn (episode i uses kind i mod len)."""
    val_signals: tuple[str, ...] = ("multisine",)
    """Signal kinds of validation episodes, used in turn."""
    test_signals: tuple[str, ...] = ("steps",)
    """Signal kinds of test episodes, used in turn."""
    seed: int = 0
    """Root seed; every episode gets its own child seed."""
    workers: int = 1
    """Parallel processes (output does not depend on it)."""
    rate_hz: float = 20.0
    """Sample (control) rate [Hz]."""
    delay_s: float = 0.05
    """Actuation delay [s]."""
    xml: str = ""
    """MJCF file; empty = the packaged excavator."""
    pose_margin: float = 0.1
    """Random initial poses keep this fraction of each joint's range from its limits."""
    limit_margin: float = 0.05
    """Excitation keeps the nominal angle this far from the end stops [rad]."""
    condition: str = "noload"
    """Operating condition recorded in the episodes."""
    record_truth: bool = True
    """Also write theta_<j>_true / omega_<j>_true (equal to the measured columns here)."""
    excitation: ExcitationConfig = field(default_factory=ExcitationConfig)
    """Parameters of the signal kinds (``[simulate.excitation.<kind>]``)."""
    plant: str = "ideal"
    """``ideal`` (Stage I servo plant) or ``hydraulic`` (Stage II stand-in, docs/hydraulics.md)."""
    hydraulics: HydraulicConfig = field(default_factory=HydraulicConfig)
    """Hydraulic effects of the ``hydraulic`` plant (``[simulate.hydraulics]``)."""
    soil: SoilConfig = field(default_factory=SoilConfig)
    """Soil contact and payload (compound operation, ``[simulate.soil]``, off by default)."""
    sensors: bool = False
    """Apply the sensor-fault model: theta/omega become measurements, truth in *_true columns."""
    sensor: SensorConfig = field(default_factory=SensorConfig)
    """Sensor noise and fault magnitudes (``[simulate.sensor]``)."""
    inputs: tuple[str, ...] = ()
    """Exogenous inputs to record as command columns ``u_<name>``: ``throttle`` (the engine
    throttle of the ``dig_session`` operator, a fraction of full; 1 for other kinds)."""
    val_s: float = 0.0
    """Split in time: cut this much of each training episode's end, before ``test_s``, into a
    validation episode [s] (0: none; docs/real.md, "One long log")."""
    test_s: float = 0.0
    """Split in time: cut this much of each training episode's end into a test episode [s]."""
    days: tuple[int, ...] = ()
    """Sessions per day, in dataset order (train, val, test; a day may log none): the sessions
    of a day share its draw of ``hydraulics.day_slowdown``.  Empty: no days."""

    def __post_init__(self) -> None:
        config_mod.check_types(self, "[simulate]")  # a wrong type: one line, before the checks
        self._check_rate()
        if not (math.isfinite(self.delay_s) and self.delay_s >= 0):
            raise ConfigError(
                f"simulate.delay_s = {self.delay_s:g} must be >= 0 [s] (the actuation delay; "
                "the packaged excavator's: 0.05)"
            )
        if self.seed < 0:
            raise ConfigError(f"simulate.seed must be >= 0, got {self.seed}")
        for name in ("n_train", "n_val", "n_test"):
            if getattr(self, name) < 0:
                raise ConfigError(f"simulate.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("steps_train", "steps_val", "steps_test"):
            if getattr(self, name) < 2:
                raise ConfigError(f"simulate.{name} must be >= 2, got {getattr(self, name)}")
        for name in ("train_signals", "val_signals", "test_signals"):
            kinds = getattr(self, name)
            if not kinds:
                raise ConfigError(f"simulate.{name} must list at least one signal kind")
            bad = [k for k in kinds if k not in SIGNALS and k not in CLOSED_LOOP]
            if bad:
                raise ConfigError(
                    f"simulate.{name}: unknown signal kind(s) {bad}; choose from "
                    f"{', '.join([*SIGNALS, *CLOSED_LOOP])}"
                )
        if self.n_train + self.n_val + self.n_test == 0:
            raise ConfigError("simulate: n_train + n_val + n_test is 0, nothing to generate")
        if self.workers < 1:
            raise ConfigError(f"simulate.workers must be >= 1, got {self.workers}")
        if not 0 <= self.pose_margin < 0.5:
            raise ConfigError(f"simulate.pose_margin must be in [0, 0.5), got {self.pose_margin}")
        bad_in = sorted(set(self.inputs) - set(INPUTS))
        if bad_in:
            raise ConfigError(
                f"simulate.inputs: unknown input(s) {bad_in}; choose from {', '.join(INPUTS)}"
            )
        for name in ("val_s", "test_s"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ConfigError(f"simulate.{name} must be >= 0 [s], got {getattr(self, name)}")
        n_episode = self.n_train + self.n_val + self.n_test
        if self.days and (min(self.days) < 0 or sum(self.days) != n_episode):
            raise ConfigError(
                f"simulate.days {list(self.days)} must count each of the {n_episode} sessions "
                "(n_train + n_val + n_test) once, with no day below 0"
            )
        if self.days and self.plant != "hydraulic":
            raise ConfigError("simulate.days needs plant = 'hydraulic' (the day's slow-down)")
        if self.plant not in SOURCES:
            raise ConfigError(
                f"simulate.plant must be one of {', '.join(SOURCES)}, got {self.plant!r}"
            )

    def _check_rate(self) -> None:
        """Refuse a ``rate_hz`` the simulator cannot sample at, before anything is simulated:
        not positive, below :data:`MIN_RATE_HZ`, or (packaged MJCF) a sample period that is not
        a whole number of its physics steps; a custom ``xml``'s timestep is checked when its
        plant loads (:class:`~.plant.MujocoExcavator`, also before any episode)."""
        rate = self.rate_hz
        step = packaged_timestep() if not self.xml else None
        if not (math.isfinite(rate) and rate > 0):
            why = "is not a sample rate"
        elif rate < MIN_RATE_HZ:
            why = (
                f"samples every {1.0 / rate:g} s, too slowly for the excavator's moves (a full "
                "stroke takes 3-4 s)"
            )
        elif step is not None and not rate_fits(rate, step):
            why = (
                f"has a sample period of {1.0 / rate:g} s, not a whole number of the packaged "
                f"excavator's {step * 1000:g} ms physics steps"
            )
        else:
            return
        if step is None:
            works = f"use {MIN_RATE_HZ:g} Hz or more, 1/rate_hz a whole number of MJCF timesteps"
        else:
            top = 1.0 / step
            ok = [r for r in RATE_EXAMPLES if r <= top and rate_fits(r, step)]
            works = f"use {top:g} Hz / n from {MIN_RATE_HZ:g} to {top:g} Hz" + (
                f" (e.g. {', '.join(f'{r:g}' for r in ok)} Hz)" if ok else ""
            )
        raise ConfigError(f"simulate.rate_hz = {rate:g} Hz {why}; {works}")

    @property
    def source(self) -> str:
        """``source`` metadata of the generated episodes."""
        return SOURCES[self.plant]

    def episode_lengths(self) -> dict[str, list[int]]:
        """Samples of each episode the simulated dataset will hold, by split, before anything
        is simulated (the training episodes cut in time by ``val_s`` / ``test_s``, as
        :func:`~.generate.simulate_dataset` cuts them)."""
        from ..data.timesplit import time_split_sizes

        out: dict[str, list[int]] = {
            "train": [],
            "val": [self.steps_val] * self.n_val,
            "test": [self.steps_test] * self.n_test,
        }
        for _ in range(self.n_train):
            cut = time_split_sizes(
                self.steps_train, rate_hz=self.rate_hz, val_s=self.val_s, test_s=self.test_s
            )
            for n, split in cut:
                out[split].append(n)
        return out

    def plant_config(self) -> PlantConfig:
        """The plant options implied by this config (single-threaded: parallelism is per process)."""
        return PlantConfig(xml=self.xml, rate_hz=self.rate_hz, delay_s=self.delay_s, n_threads=1)
