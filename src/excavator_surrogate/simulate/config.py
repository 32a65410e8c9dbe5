"""The ``[simulate]`` table: :class:`SimulateConfig` (what ``exsur simulate`` generates,
:func:`~.generate.simulate_dataset` reads it), with the plants and the exogenous inputs a
simulation can record."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .. import config as config_mod
from ..errors import ConfigError
from ..spec import InputSpec
from .excitation import CLOSED_LOOP, SIGNALS, ExcitationConfig
from .hydraulics import HydraulicConfig
from .plant import PlantConfig
from .sensors import SensorConfig
from .soil import SoilConfig

SOURCES: dict[str, str] = {"ideal": "mujoco-ideal", "hydraulic": "mujoco-hydraulic"}
"""``source`` metadata per plant kind."""
INPUTS: dict[str, InputSpec] = {
    "throttle": InputSpec("throttle", u_min=0.0, u_max=1.0, unit="fraction of full throttle")
}
"""Exogenous inputs a simulation can record (``SimulateConfig.inputs``)."""


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
