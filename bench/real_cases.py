"""The data shapes of ``bench/real.py``: each builds its dataset, the split it is scored on,
its run-condition variant and, for the simulated shapes, more test data.

:data:`CASES` maps a shape's name to its builder; add a shape by adding a builder.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from excavator_surrogate.config import load_preset
from excavator_surrogate.data import Dataset, Episode, load_dataset, write_dataset

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "real" / "h1-dev"
MAPPING = REPO / "examples" / "real_excavator.toml"
MAPPING_CONDITION = REPO / "examples" / "real_excavator_condition.toml"
"""The same mapping plus the run names' H/L condition as a per-run input."""
STROKE_EXAMPLE = REPO / "examples" / "stroke_make_logs.py"
"""Writes the stroke-sensing machine's logs and mapping (``make_logs``)."""
MORE_TEST = {"continuous": 8, "continuous-7min": 8, "sessions": 12, "sessions-days": 12}
"""More test segments per simulated log (``--more-test`` default): 8 x 160 s of the log's
continuation, 12 more sessions of 180 s (``sessions-days``: on the test's day)."""
SHORT_LOG_S = 420.0
"""``loader-7min``: the wheel loader's own log length (7 min at 20 Hz: 160 s train | 100 s
validate | 160 s test), the first 420 s of the continuous log of the same seed."""
SIMULATED = {
    "continuous": ("continuous-dig", None),
    "continuous-7min": ("continuous-dig", SHORT_LOG_S),
    "sessions": ("sessions-dig", None),
    "sessions-days": ("sessions-days", None),
}
"""The simulated logs by name: their preset, and the length of the whole log in seconds where
it is not the preset's (train, validation and test together)."""
STEP_FIELDS = ("steps_train", "steps_val", "steps_test")
"""The simulate config's lengths in samples (``--rate-hz`` rescales them to keep seconds)."""
LOADER_BASE = {"loader": "continuous", "loader-7min": "continuous-7min"}
"""Each loader shape's simulated log (with four joints observed)."""


@dataclass
class Case:
    """One data shape: its dataset, the split it is scored on, and its condition variant."""

    dataset: Dataset
    """Train / val (/ test) episodes."""
    score_split: str
    """The split the table scores (``val`` for h1, whose test is hidden; else ``test``)."""
    split: str
    """How the data is split, in words (for the JSON)."""
    condition: Callable[[], Dataset] | None = None
    """Builds the same data with the shape's run-condition / exogenous input (``--condition``)."""
    condition_name: str = ""
    """What that input is, in words."""
    more: Sequence[Episode] = ()
    """More test data of the same machine, scored beside the split (``--more-test``; the
    simulated shapes): one test segment misranks models that many segments rank the other way."""
    more_what: str = ""
    """What ``more`` is, in words."""


def _h1(work: Path, args: argparse.Namespace) -> Case | str:
    from excavator_surrogate.ingest import import_logs
    from excavator_surrogate.ingest.mapping_toml import load_mapping

    runs_dir = args.data / "runs"
    if not runs_dir.is_dir():
        return f"no real data at {runs_dir}"
    import_logs([runs_dir], load_mapping(MAPPING), out=work / "h1", quiet=True)

    def with_condition() -> Dataset:
        import_logs([runs_dir], load_mapping(MAPPING_CONDITION), out=work / "h1_cond", quiet=True)
        return load_dataset(work / "h1_cond")

    return Case(
        load_dataset(work / "h1"),
        "val",
        "train: duty 40/60/80/90/100; scored on val: duty 50",
        with_condition,
        f"H/L run condition ({MAPPING_CONDITION.name})",
    )


HELD_OUT_DUTY = 80
"""``h1-duty80``: the duty level whose runs leave the training split to be its test."""


def _h1_duty80(work: Path, args: argparse.Namespace) -> Case | str:
    """h1-dev with the duty-80 runs held out of training as a test: a duty the models never
    saw, between two they did (60 and 90), as the hidden test's duty is.  Validation stays
    duty 50, one level near the dead zones: the split the recipe chooses on."""
    got = _h1(work, args)
    if isinstance(got, str):
        return got
    cond = got.condition
    assert cond is not None

    def with_condition() -> Dataset:
        return _held_out(cond(), work / f"h1c-duty{HELD_OUT_DUTY}")

    return Case(
        _held_out(got.dataset, work / f"h1-duty{HELD_OUT_DUTY}"),
        "test",
        f"train: duty 40/60/90/100; val: duty 50; scored on test: duty {HELD_OUT_DUTY} (held out "
        "of h1-dev's training runs, a development stand-in for the hidden test's unseen duty)",
        with_condition,
        got.condition_name,
    )


def _held_out(src: Dataset, out: Path) -> Dataset:
    """``src`` (h1-dev, imported) with the :data:`HELD_OUT_DUTY` runs moved from training to
    the test split, written to ``out``."""
    tag = f"-{HELD_OUT_DUTY}-"
    items = [(ep, "test" if tag in ep.name else "train") for ep in src.train]
    items += [(ep, "val") for ep in src.val]
    write_dataset(out, items, config=src.manifest.get("config") or None)
    return load_dataset(out)


def _as_logged(src: Dataset, out: Path, *, inputs: bool) -> Dataset:
    """``src`` as a user's import of the log would give it: no declared end stops or speed
    bounds, and the exogenous inputs only with ``inputs``."""
    spec = src.spec
    joints = tuple(
        dataclasses.replace(j, theta_min=None, theta_max=None, omega_max=None) for j in spec.joints
    )
    spec = dataclasses.replace(spec, joints=joints, inputs=spec.inputs if inputs else ())
    items = [(ep, s) for s in ("train", "val", "test") for ep in as_spec(src.split(s), spec)]
    write_dataset(out, items, config=src.manifest.get("config") or None)
    return load_dataset(out)


def sim_config(name: str, sim_seed: int, rate_hz: float | None = None):
    """The simulate config of the simulated log ``name`` (:data:`SIMULATED`), seed ``sim_seed``;
    ``rate_hz``: logged at this rate instead of the preset's (every length in seconds kept)."""
    from excavator_surrogate.simulate.config import SimulateConfig

    preset, total_s = SIMULATED[name]
    cfg = SimulateConfig.from_preset(load_preset(preset), seed=sim_seed)
    if rate_hz is not None and rate_hz != cfg.rate_hz:
        steps = {k: round(getattr(cfg, k) * rate_hz / cfg.rate_hz) for k in STEP_FIELDS}
        cfg = dataclasses.replace(cfg, rate_hz=rate_hz, **steps)
    if total_s is not None:
        cfg = dataclasses.replace(cfg, steps_train=round(total_s * cfg.rate_hz))
    return cfg


def _simulated(
    work: Path,
    args: argparse.Namespace,
    name: str,
    split: Callable[..., str],
    more: Callable[..., tuple[list[Episode], str]],
) -> Case:
    """The stand-in log ``name`` (:data:`SIMULATED`, seed ``--sim-seed``) as imported
    (``_as_logged``), its engine throttle as the condition variant; ``split(cfg)`` says how it
    is split, and ``more(cfg, sim, n, out)`` simulates ``n`` more test segments
    (``--more-test``)."""
    from excavator_surrogate.simulate.generate import simulate_dataset

    cfg = sim_config(name, args.sim_seed, args.rate_hz)
    simulate_dataset(cfg, out=work / f"{name}_sim")
    sim = load_dataset(work / f"{name}_sim")
    n_more = MORE_TEST[name] if args.more_test is None else args.more_test
    extra, what = more(cfg, sim, n_more, work / f"{name}_more") if n_more > 0 else ([], "")
    return Case(
        _as_logged(sim, work / name, inputs=False),
        "test",
        split(cfg),
        lambda: _as_logged(sim, work / f"{name}_throttle", inputs=True),
        "engine throttle u_throttle",
        more=extra,
        more_what=what,
    )


def _more_in_time(cfg, sim: Dataset, n: int, out: Path) -> tuple[list[Episode], str]:
    """The same log ``n`` test lengths longer: its continuation, cut into ``n`` segments of the
    test's length (the same seed draws the same operator and plant, so the first part is the
    log the case trains on, which is checked)."""
    from excavator_surrogate.simulate.generate import simulate_dataset

    n_test = round(cfg.test_s * cfg.rate_hz)
    longer = dataclasses.replace(
        cfg, steps_train=cfg.steps_train + n * n_test, val_s=0.0, test_s=0.0
    )
    (ep,) = load_dataset(simulate_dataset(longer, out=out)).train
    logged = np.concatenate([e.theta for e in sim.train + sim.val + sim.test])
    if not np.array_equal(ep.theta[: cfg.steps_train], logged):
        raise RuntimeError(f"{out}: the longer log does not continue the case's log")
    return _segments(cfg, ep, n), f"the log's next {n} x {cfg.test_s:g} s after the test"


def _segments(cfg, ep: Episode, n: int) -> list[Episode]:
    """The ``n`` test-length segments of the longer log ``ep`` after the case's own log."""
    n_test = round(cfg.test_s * cfg.rate_hz)
    start = cfg.steps_train
    return [ep.slice(start + i * n_test, start + (i + 1) * n_test) for i in range(n)]


def _more_sessions(cfg, sim: Dataset, n: int, out: Path) -> tuple[list[Episode], str]:
    """``n`` more test sessions: test episodes ``1 .. n`` of the same seed (each episode's seed
    depends on its split and index only, so episode 0 is the case's test, which is checked);
    with days, all on the test's day (which draws the same slow-down as in the case)."""
    from excavator_surrogate.simulate.generate import simulate_dataset

    days = (0,) * (len(cfg.days) - 1) + (1 + n,) if cfg.days else ()
    more = dataclasses.replace(cfg, n_train=0, n_val=0, n_test=1 + n, days=days)
    test = load_dataset(simulate_dataset(more, out=out)).test
    if not np.array_equal(test[0].theta, sim.test[0].theta):
        raise RuntimeError(f"{out}: the first test session is not the case's")
    where = " on the test's day" if cfg.days else ""
    return list(test[1:]), f"{n} more test sessions of {cfg.steps_test / cfg.rate_hz:.0f} s{where}"


def saved_more(
    work: Path, name: str, sim_seed: int, spec, rate_hz: float | None = None
) -> list[Episode]:
    """The more test data that ``python bench/real.py --work WORK`` simulated for the shape
    ``name`` (``WORK/<log>_more`` of its simulated log, a loader shape's its
    :data:`LOADER_BASE`; none for h1 and stroke), as a dataset of ``spec`` holds them,
    without simulating anything."""
    base = LOADER_BASE.get(name, name)
    if base not in MORE_TEST or not (work / f"{base}_more").is_dir():
        return []
    more = load_dataset(work / f"{base}_more")
    if base.startswith("sessions"):
        return as_spec(more.test[1:], spec)
    cfg = sim_config(base, sim_seed, rate_hz)
    (ep,) = more.train
    n_test = round(cfg.test_s * cfg.rate_hz)
    segments = _segments(cfg, ep, (len(ep.theta) - cfg.steps_train) // n_test)
    if name in LOADER_BASE:
        segments = _observed(segments, spec, LOADER_JOINTS)
    return as_spec(segments, spec)


def as_spec(episodes: Sequence[Episode], spec) -> list[Episode]:
    """``episodes`` (as simulated) as a dataset of ``spec`` holds them (``_as_logged``)."""
    return [e.replace(spec=spec, u=e.u[:, : spec.n_u]) for e in episodes]


def _in_time(cfg) -> str:
    return (
        f"one {cfg.steps_train / cfg.rate_hz:.0f}-s log in time: train | {cfg.val_s:g} s val | "
        f"{cfg.test_s:g} s test (scored)"
    )


def _by_session(cfg) -> str:
    days = (
        f"; {len(cfg.days)} days of {'/'.join(map(str, cfg.days))} sessions, each day its own "
        f"speed (up to {cfg.hydraulics.day_slowdown:.0%} slower), the last day validates and "
        "tests"
        if cfg.days
        else ""
    )
    return (
        f"{cfg.n_train} sessions of {cfg.steps_train / cfg.rate_hz:.0f} s train | {cfg.n_val} "
        f"validate | 1 of {cfg.steps_test / cfg.rate_hz:.0f} s tests (scored); each session "
        f"its own oil temperature (up to {cfg.hydraulics.drift_amplitude:.0%} slower cold)"
        f"{days}"
    )


def _continuous(work: Path, args: argparse.Namespace) -> Case:
    return _simulated(work, args, "continuous", _in_time, _more_in_time)


def _observed(episodes: Sequence[Episode], spec, keep: Sequence[int]) -> list[Episode]:
    """``episodes`` with only the joints ``keep`` (their angles and commands; every exogenous
    input column stays, for :func:`as_spec` to keep or drop), as joints of ``spec``."""

    def cols(e: Episode) -> list[int]:
        return [*keep, *range(e.spec.n_joint, e.u.shape[1])]

    def cut(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[:, list(keep)]

    return [
        e.replace(
            spec=spec,
            u=e.u[:, cols(e)],
            theta=e.theta[:, list(keep)],
            omega=e.omega[:, list(keep)],
            theta_true=cut(e.theta_true),
            omega_true=cut(e.omega_true),
            trusted=cut(e.trusted),
        )
        for e in episodes
    ]


def _two_joints(src: Dataset, out: Path, keep: Sequence[int]) -> Dataset:
    """``src`` with only the joints ``keep`` observed and commanded (the others still move)."""
    spec = dataclasses.replace(src.spec, joints=tuple(src.spec.joints[i] for i in keep))
    items = [
        (ep, s) for s in ("train", "val", "test") for ep in _observed(src.split(s), spec, keep)
    ]
    write_dataset(out, items, config=src.manifest.get("config") or None)
    return load_dataset(out)


LOADER_JOINTS = (1, 3)
"""The joints the loader shape observes: boom and bucket (a wheel loader's two)."""


def _loader_of(name: str, work: Path, args: argparse.Namespace) -> Case:
    """The loader shape ``name``: its simulated log (:data:`LOADER_BASE`) with only the
    :data:`LOADER_JOINTS` observed and commanded."""
    case = _simulated(work, args, LOADER_BASE[name], _in_time, _more_in_time)
    data = _two_joints(case.dataset, work / name, LOADER_JOINTS)
    cond = case.condition
    assert cond is not None
    return dataclasses.replace(
        case,
        dataset=data,
        split=f"{case.split}; only the boom and the bucket observed (the swing and arm move)",
        condition=lambda: _two_joints(cond(), work / f"{name}_throttle", LOADER_JOINTS),
        more=_observed(case.more, data.spec, LOADER_JOINTS),
    )


def _loader(work: Path, args: argparse.Namespace) -> Case:
    return _loader_of("loader", work, args)


def _loader_7min(work: Path, args: argparse.Namespace) -> Case:
    """The loader shape at the wheel loader's own length: 160 s train | 100 s | 160 s."""
    return _loader_of("loader-7min", work, args)


def _sessions(work: Path, args: argparse.Namespace) -> Case:
    return _simulated(work, args, "sessions", _by_session, _more_sessions)


def _sessions_days(work: Path, args: argparse.Namespace) -> Case:
    """The sessions in days, each day its own speed: validation is the test's day."""
    return _simulated(work, args, "sessions-days", _by_session, _more_sessions)


def _stroke(work: Path, args: argparse.Namespace) -> Case:
    import importlib.util

    from excavator_surrogate.ingest import import_logs
    from excavator_surrogate.ingest.mapping_toml import load_mapping

    spec = importlib.util.spec_from_file_location("stroke_make_logs", STROKE_EXAMPLE)
    assert spec is not None and spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    mapping = example.make_logs(work / "stroke_logs", seed=args.sim_seed, preset="quick-hydraulic")
    import_logs(
        [work / "stroke_logs" / "logs"], load_mapping(mapping), out=work / "stroke", quiet=True
    )
    return Case(
        load_dataset(work / "stroke"),
        "test",
        "quick-hydraulic's runs as a stroke-sensing machine's CSV logs (swing in deg; boom, "
        "arm, bucket cylinder strokes in mm): its own train / val / test (scored)",
    )


CASES: dict[str, Callable[[Path, argparse.Namespace], Case | str]] = {
    "h1": _h1,
    "h1-duty80": _h1_duty80,
    "continuous": _continuous,
    "sessions": _sessions,
    "sessions-days": _sessions_days,
    "stroke": _stroke,
    "loader": _loader,
    "loader-7min": _loader_7min,
}
"""Data shapes by name: ``builder(work_dir, args) -> Case`` (or a reason to skip it)."""
