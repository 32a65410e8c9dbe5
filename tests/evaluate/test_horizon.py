"""The prediction-horizon scores: batched starts against a plain loop of single ClosedLoop
runs, the hold baseline on known motion, and what evaluate writes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from excavator_surrogate.data.episode import Episode
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.evaluate import horizon as H
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.rollout import ClosedLoop
from tests.helpers.surrogates import tiny_surrogate

DT = EXCAVATOR.dt


def _episode(rng: np.random.Generator, n_step: int, name: str) -> Episode:
    theta = np.array([3.0, 0.0, 1.5, 0.5]) + rng.normal(0, 0.02, (n_step, 4)).cumsum(axis=0)
    theta[:, 0] = (theta[:, 0] + math.pi) % (2 * math.pi) - math.pi  # the swing stored wrapped
    u = rng.uniform(-1000, 1000, (n_step, 4))
    omega = np.zeros_like(theta)
    return Episode(EXCAVATOR, np.arange(n_step) * DT, u, theta, omega, name=name)


def _wrap(d: np.ndarray) -> np.ndarray:
    d = d.copy()
    d[..., 0] = (d[..., 0] + math.pi) % (2 * math.pi) - math.pi
    return d


@pytest.mark.parametrize("mode", ["stateful", "windowed"])
def test_batched_starts_equal_single_closed_loop_runs(mode: str, monkeypatch) -> None:
    """Every start warmed up on the W samples before it and run alone, the squared errors
    pooled by hand: the same RMSE per horizon and joint (in chunks smaller than the starts,
    episodes shorter than the longest horizon, a swing stored wrapped); hold too."""
    monkeypatch.setattr(H, "CHUNK", 4)  # several chunks per episode
    sur = tiny_surrogate(mode=mode, window=5)
    rng = np.random.default_rng(0)
    eps = [_episode(rng, 37, "a"), _episode(rng, 23, "b")]
    got = H.horizon_errors(
        {"m": sur}, eps, spec=EXCAVATOR, horizons_s=(0.1, 0.5, 1.0), stride_s=0.1
    )
    w, stride, n_max = 5, 2, 20
    sq = {"m": np.zeros((n_max, 4)), "hold": np.zeros((n_max, 4))}
    count = np.zeros(n_max)
    n_start = 0
    for ep in eps:
        n = len(ep.u)
        for k in range(w - 1, n - 1, stride):
            n_start += 1
            loop = ClosedLoop(sur)
            loop.reset(ep.theta[None, k - w + 1 : k + 1], ep.u[None, k - w + 1 : k])
            for j in range(min(n_max, n - 1 - k)):
                th = loop.step(ep.u[None, k + j])[0][0].double().numpy()
                sq["m"][j] += _wrap(th - ep.theta[k + j + 1]) ** 2
                sq["hold"][j] += _wrap(ep.theta[k] - ep.theta[k + j + 1]) ** 2
                count[j] += 1
    assert got["steps"] == [2, 10, 20] and got["n_start"] == n_start == 16 + 9
    for label in ("m", "hold"):
        for i, name in enumerate(EXCAVATOR.names):
            want = [math.sqrt(sq[label][s - 1, i] / count[s - 1]) for s in (2, 10, 20)]
            np.testing.assert_allclose(got["rmse"][label][name], want, rtol=1e-6)
            curve = got["curve"]["rmse"][label][name]
            np.testing.assert_allclose(curve, np.sqrt(sq[label][:, i] / count), rtol=1e-6)


def test_hold_on_known_motion_and_horizons_no_start_reaches() -> None:
    """A joint moving at a constant 0.2 rad/s: hold is off by 0.2·t at horizon t, the
    swing wrapped across ±π is off by the same, not by 2π; a horizon longer than the
    episode has no start (None) and the table shows a dash."""
    n = 30
    t = np.arange(n) * DT
    theta = np.tile([3.1, 0.0, 1.5, 0.5], (n, 1)) + 0.2 * t[:, None]
    theta[:, 0] = (theta[:, 0] + math.pi) % (2 * math.pi) - math.pi
    ep = Episode(EXCAVATOR, t, np.zeros((n, 4)), theta, np.zeros_like(theta), name="ramp")
    sur = tiny_surrogate(window=3)
    got = H.horizon_errors({"m": sur}, [ep], spec=EXCAVATOR, horizons_s=(0.5, 1.0, 5.0))
    for name in EXCAVATOR.names:
        hold = got["rmse"]["hold"][name]
        assert hold[0] == pytest.approx(0.2 * 0.5) and hold[1] == pytest.approx(0.2 * 1.0)
        assert hold[2] is None and got["rmse"]["m"][name][2] is None
    table = H.horizon_markdown(got)
    assert "| Swing [°] | m |" in table and "| — |" in table
    assert f"{math.degrees(0.1):.3g}" in table  # hold at 0.5 s, in degrees


def test_bad_options_are_one_line() -> None:
    sur = tiny_surrogate()
    with pytest.raises(ConfigError, match=r"horizons must be seconds > 0"):
        H.horizon_errors({"m": sur}, [], spec=EXCAVATOR, horizons_s=(1.0, -2.0))
    with pytest.raises(ConfigError, match=r"horizon_stride must be seconds > 0"):
        H.horizon_errors({"m": sur}, [], spec=EXCAVATOR, stride_s=0.0)
    with pytest.raises(ConfigError, match=r"'hold' names the no-motion baseline"):
        H.horizon_errors({"hold": sur}, [], spec=EXCAVATOR)


def test_evaluate_writes_the_horizon_table_figure_and_json(tmp_path) -> None:
    """``exsur evaluate`` scores the model and its baselines at the horizons, draws
    horizon.png and puts the table in table.md; ``horizons = []`` writes none of them (and
    an earlier figure in the folder goes)."""
    from excavator_surrogate.data import write_dataset
    from excavator_surrogate.data.dataset import load_dataset
    from excavator_surrogate.evaluate import evaluate_checkpoint
    from excavator_surrogate.outdir import foreign_entry
    from excavator_surrogate.surrogate.checkpoint import load_checkpoint, save_checkpoint
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
    from tests.helpers.surrogates import make_surrogate

    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=2, n_step=120, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    ckpt = save_checkpoint(tmp_path / "m.pt", make_surrogate(ds.spec, ds.train, window=5))
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", horizons=(0.5, 1.0))
    hz = res["horizon"]
    assert list(hz["rmse"]) == [
        load_checkpoint(ckpt).name.upper(),
        "ARX",
        "Structured",
        "hold",
    ]
    assert hz["n_start"] > 0
    assert (tmp_path / "ev" / "horizon.png").is_file()
    assert "## Prediction horizon" in (tmp_path / "ev" / "table.md").read_text()
    # every file of it is exsur's: a second evaluation (or a resumed run) may write there
    assert foreign_entry(tmp_path / "ev") is None
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", horizons=(), arx=False)
    assert "horizon" not in res and not (tmp_path / "ev" / "horizon.png").exists()
    assert "Prediction horizon" not in (tmp_path / "ev" / "table.md").read_text()


def test_the_cli_passes_every_evaluate_field(tmp_path) -> None:
    """``exsur evaluate --set evaluate.horizons=[...]`` reaches the evaluation (the CLI
    passes the whole [evaluate] table, as exsur run does)."""
    from excavator_surrogate.cli import main
    from excavator_surrogate.data import write_dataset
    from excavator_surrogate.surrogate.checkpoint import save_checkpoint
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
    from tests.helpers.surrogates import make_surrogate

    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=1, n_val=1, n_test=1, n_step=120, noise=0.001)
    data = write_dataset(tmp_path / "data", items)
    ckpt = save_checkpoint(tmp_path / "m.pt", make_surrogate(spec, [items[0][0]], window=5))
    base = ["evaluate", str(ckpt), str(data), "--no-arx", "-q"]
    assert main([*base, "--out", str(tmp_path / "a"), "--set", "evaluate.horizons=[0.25]"]) == 0
    got = json.loads((tmp_path / "a" / "metrics.json").read_text())["horizon"]
    assert got["horizons_s"] == [0.25] and (tmp_path / "a" / "horizon.png").is_file()
    assert main([*base, "--out", str(tmp_path / "b"), "--set", "evaluate.horizons=[]"]) == 0
    assert "horizon" not in json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert not (tmp_path / "b" / "horizon.png").exists()
