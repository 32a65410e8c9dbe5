"""Where the error is: each episode's angle RMSE and share of the pooled squared error, the
table that lists them and the episodes the figures show."""

from __future__ import annotations

import math

import numpy as np
import pytest

from excavator_surrogate.evaluate import cbe_metrics, episode_errors
from excavator_surrogate.evaluate.cbe import figure_episodes
from excavator_surrogate.evaluate.report import episodes_markdown
from excavator_surrogate.spec import JointSpec, MachineSpec
from tests.helpers.runs import Run

SPEC = MachineSpec(joints=(JointSpec("swing", periodic=True), JointSpec("boom")))


def _runs(rng: np.random.Generator, lengths: list[int], w: int = 3) -> list[Run]:
    runs = []
    for n in lengths:
        ref = np.cumsum(rng.normal(0.0, 0.2, (n, 2)), axis=0)
        hat = ref + rng.normal(0.0, rng.uniform(0.01, 0.3), (n, 2))
        hat[:w] = 99.0  # the warm-up is never scored
        wrapped = ref.copy()
        wrapped[:, 0] = (wrapped[:, 0] + np.pi) % (2 * np.pi) - np.pi  # the swing stored wrapped
        om = np.zeros((n, 2))
        runs.append(Run(hat, om, wrapped, om, w))
    return runs


def test_each_episodes_rmse_and_share_against_a_plain_loop():
    runs = _runs(np.random.default_rng(0), [20, 35, 12, 50])
    got = episode_errors(runs, SPEC)
    sse = np.zeros((len(runs), 2))
    for e, r in enumerate(runs):
        ref = np.unwrap(r.theta_ref, axis=0)
        for j in range(2):
            for k in range(r.warmup, len(ref)):
                sse[e, j] += (r.theta_hat[k, j] - ref[k, j]) ** 2
    for e, r in enumerate(runs):
        for j, name in enumerate(SPEC.names):
            n = len(r.theta_hat) - r.warmup
            assert got[e]["theta_rmse"][name] == pytest.approx(math.sqrt(sse[e, j] / n))
            assert got[e]["theta_share"][name] == pytest.approx(sse[e, j] / sse[:, j].sum())
    # the shares rebuild the pooled RMSE the table gives
    pooled = cbe_metrics(runs, SPEC)["theta"]
    n_all = sum(len(r.theta_hat) - r.warmup for r in runs)
    for j, name in enumerate(SPEC.names):
        assert sum(g["theta_share"][name] for g in got) == pytest.approx(1.0)
        assert pooled[name]["rmse"] == pytest.approx(math.sqrt(sse[:, j].sum() / n_all))


def test_no_error_and_a_diverged_run_have_no_share():
    runs = _runs(np.random.default_rng(1), [10, 10])
    for r in runs:  # exact on both joints
        r.theta_hat = np.unwrap(r.theta_ref, axis=0).copy()
    got = episode_errors(runs, SPEC)
    assert all(g["theta_share"] == {"swing": None, "boom": None} for g in got)
    assert got[0]["theta_rmse"]["boom"] == 0.0
    runs[1].theta_hat[5, 1] = np.nan
    got = episode_errors(runs, SPEC)
    assert got[1]["theta_rmse"]["boom"] is None and got[0]["theta_share"]["boom"] is None


def _episodes(shares: list[tuple[float, float]]) -> list[dict]:
    return [
        {
            "name": f"run{i}",
            "n_step": 10,
            "theta_rmse": {"swing": 0.1 * i, "boom": 0.01 * i},
            "theta_share": {"swing": a, "boom": b},
        }
        for i, (a, b) in enumerate(shares)
    ]


def test_the_figures_show_the_first_episode_then_the_largest_shares():
    eps = _episodes([(0.1, 0.1), (0.05, 0.1), (0.6, 0.1), (0.05, 0.5), (0.2, 0.2)])
    assert figure_episodes(eps, 4) == [0, 2, 3, 4]
    assert figure_episodes(eps, 1) == [0]
    assert figure_episodes(eps, 0) == []
    assert figure_episodes(eps, 99) == [0, 2, 3, 4, 1]
    assert figure_episodes(eps[:1], 4) == [0]


def test_the_table_lists_each_joints_largest_shares_with_their_rmse():
    eps = _episodes([(0.1, 0.1), (0.05, 0.1), (0.6, 0.1), (0.05, 0.5), (0.2, 0.2)])
    md = episodes_markdown(eps, figures=["cbe.png", "cbe_run2.png"])
    rows = [line for line in md.splitlines() if line.startswith("| ")][1:]
    assert rows[0] == "| Swing | run2 | 0.2000 | 60 % |"
    assert rows[1] == "|  | run4 | 0.4000 | 20 % |"
    assert rows[3] == "| Boom | run3 | 0.0300 | 50 % |"
    assert len(rows) == 6 and "`cbe_run2.png`" in md and "[rad]" in md
    assert episodes_markdown(eps[:1]) == ""  # one episode: the table above is that episode


def test_a_linear_joint_prints_in_its_own_unit():
    spec = MachineSpec(
        joints=(JointSpec("boom", kind="linear", unit="mm"), JointSpec("arm")),
    )
    eps = [
        {
            "name": f"r{i}",
            "theta_rmse": {"boom": 0.002, "arm": 0.1},
            "theta_share": {"boom": 0.5, "arm": 0.5},
        }
        for i in range(2)
    ]
    md = episodes_markdown(eps, spec=spec)
    assert "| Boom [mm] | r0 | 2.0000 | 50 % |" in md and "[rad]" not in md.splitlines()[4]


def test_evaluate_records_each_episodes_error_and_draws_the_worst(tmp_path):
    from excavator_surrogate.data import write_dataset
    from excavator_surrogate.data.dataset import load_dataset
    from excavator_surrogate.evaluate import evaluate_checkpoint
    from excavator_surrogate.surrogate.checkpoint import save_checkpoint
    from excavator_surrogate.surrogate.synthetic import synthetic_spec, synthetic_split
    from tests.helpers.surrogates import make_surrogate

    spec = synthetic_spec(2)
    items = synthetic_split(spec, n_train=2, n_val=1, n_test=4, n_step=120, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    ckpt = save_checkpoint(
        tmp_path / "m.pt", make_surrogate(ds.spec, ds.train, mode="stateful", window=5)
    )
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", max_figures=2, arx=False)
    eps = res["run"]["episodes"]
    assert [e["name"] for e in eps] == [e.name for e in ds.test]
    for name in ds.spec.names:
        assert sum(e["theta_share"][name] for e in eps) == pytest.approx(1.0)
    worst = figure_episodes(eps, 2)[1]
    assert worst != 0
    drawn = sorted(p.name for p in (tmp_path / "ev").glob("cbe*.png"))
    assert drawn == sorted(["cbe.png", f"cbe_{eps[worst]['name']}.png"])
    table = (tmp_path / "ev" / "table.md").read_text()
    assert "## Where the error is" in table and f"`cbe_{eps[worst]['name']}.png`" in table
    # evaluated again into the same folder with one figure: the earlier episode figure goes
    evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", max_figures=1, arx=False)
    assert sorted(p.name for p in (tmp_path / "ev").glob("cbe*.png")) == ["cbe.png"]
