"""Exogenous inputs must not hurt: ``exogenous = "ignore"`` and ``"choose"``."""

from __future__ import annotations

import csv
import math
import tomllib

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.data.episode import Episode
from excavator_surrogate.spec import InputSpec, JointSpec, MachineSpec
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, read_checkpoint
from excavator_surrogate.training import train
from excavator_surrogate.training.variants import INPUT_MARGIN, choose_inputs
from tests.helpers.training import tiny_train_config

SPEC = MachineSpec(
    joints=(JointSpec("boom", theta_min=-1.2, theta_max=1.2),),
    rate_hz=20.0,
    name="gear-1j",
    inputs=(InputSpec("gear", u_min=-1.0, u_max=1.0),),
)


def _episode(seed: int, *, informative: bool, n_step: int = 200) -> Episode:
    """One joint driven by a sine command and the exogenous ``gear`` (+1 / -1, held for 40
    samples), which adds to its speed (``informative``) or is pure noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_step) / SPEC.rate_hz
    cmd = 0.8 * np.sin(2 * math.pi * rng.uniform(0.1, 0.3) * t + rng.uniform(0, 6.3))
    gear = np.repeat(rng.choice([-1.0, 1.0], n_step // 40 + 1), 40)[:n_step]
    speed = 0.5 * cmd + (0.3 * gear if informative else 0.0)
    theta = np.zeros(n_step)
    for k in range(1, n_step):
        theta[k] = np.clip(theta[k - 1] + speed[k - 1] / SPEC.rate_hz, -1.1, 1.1)
    omega = np.concatenate([[0.0], np.diff(theta) * SPEC.rate_hz])
    return Episode(
        spec=SPEC,
        time=t,
        u=np.stack([cmd, gear], axis=1),
        theta=theta[:, None],
        omega=omega[:, None],
        name=f"ep{seed}",
    )


def _dataset(*, informative: bool) -> Dataset:
    ds = Dataset(spec=SPEC)
    ds.episodes["train"] = [_episode(s, informative=informative) for s in range(4)]
    ds.episodes["val"] = [_episode(50, informative=informative)]
    return ds


def _cfg(**kw):
    return tiny_train_config(
        window=5, hidden=12, head_hidden=12, seq_len=40, burn_in=5, epochs=6, lr=1e-2, **kw
    )


def _gear_effect(ckpt) -> float:
    """Largest change of the predicted omega when the gear column is flipped."""
    sur = load_checkpoint(ckpt)
    ep = _episode(7, informative=True)
    x = [
        sur.norm.encode(torch.tensor(ep.theta, dtype=torch.float32), torch.tensor(u))
        for u in (
            ep.u.astype(np.float32),
            (ep.u * np.array([1.0, -1.0])).astype(np.float32),
        )
    ]
    with torch.no_grad():
        y = [sur.net.forward_seq(xi[None])[0] for xi in x]
    return float((y[0] - y[1]).abs().max())


def test_ignored_inputs_cannot_change_the_prediction(tmp_path):
    ds = _dataset(informative=True)
    ignored = train(_cfg(exogenous="ignore"), ds, out=tmp_path / "i", show_progress=False)
    used = train(_cfg(exogenous="use"), ds, out=tmp_path / "u", show_progress=False)
    assert _gear_effect(ignored) == 0.0  # the gear's weights are held at exactly zero
    assert _gear_effect(used) > 1e-3  # the same training with the input uses it
    w = load_checkpoint(ignored).net.rnn.weight_ih_l0
    assert torch.count_nonzero(w[:, -1]) == 0 and torch.count_nonzero(w[:, :-1]) > 0


@pytest.mark.parametrize("informative", [True, False])
def test_choose_keeps_an_informative_input_and_ignores_a_noise_one(tmp_path, informative):
    ds = _dataset(informative=informative)
    cfg = _cfg(exogenous="choose", members=2, member_workers=1)  # in this process
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    record = ck["metrics"]["training"]["exogenous"]
    assert record["kept"] is informative, record["why"]
    way = "use" if informative else "ignore"
    assert ck["train_config"]["exogenous"] == way and ck["train_config"]["members"] == 2
    assert (_gear_effect(best) > 1e-3) is informative
    # both halves were trained on the same seed, the rest the chosen way
    lost = "ignore" if informative else "use"
    for d in (f"{lost}/member_0", "member_0", "member_1"):  # exsur run reads OUT/member_<i>
        assert (tmp_path / "m" / d / "best.pt").is_file()
    assert not (tmp_path / "m" / way).exists()
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    assert [r["exogenous"] for r in rows] == [way, way, way]
    notes = tomllib.loads((tmp_path / "m" / "config.toml").read_text())
    assert notes["train"]["exogenous"] == "choose" and notes["exogenous"]["kept"] is informative


def test_choose_without_inputs_trains_as_before(tmp_path):
    from tests.helpers.training import tiny_dataset

    best = train(
        tiny_train_config(epochs=1, exogenous="choose"),
        tiny_dataset(2, n_train=1),
        out=tmp_path / "p",
        show_progress=False,
    )
    assert "exogenous" not in read_checkpoint(best)["metrics"]["training"]
    assert not (tmp_path / "p" / "use").exists()


def _val(err, rmse):
    return {"val_error": err, "theta_rmse": rmse}


def test_inputs_are_kept_only_if_better_overall_and_on_every_joint():
    m = INPUT_MARGIN
    assert choose_inputs(_val(0.5, [1.0, 1.0]), _val(1.0, [2.0, 2.0]))[0]
    # a tie (within the margin) keeps the model that cannot depend on them
    assert not choose_inputs(_val(1.0 - m / 2, [1.0, 1.0]), _val(1.0, [1.0, 1.0]))[0]
    # better overall, but one joint worse: they would hurt that joint
    keep, why = choose_inputs(_val(0.5, [0.2, 2.2]), _val(1.0, [2.0, 2.0]))
    assert not keep and "[1]" in why
    assert not choose_inputs(_val(math.inf, [math.nan, 1.0]), _val(1.0, [1.0, 1.0]))[0]


def test_choose_with_the_kind_choice_trains_the_map_correcting_networks_the_chosen_way(tmp_path):
    """The inputs are chosen first; the rest of the plain ensemble and the map-correcting
    networks then train the chosen way, and the kind choice runs on them."""
    ds = _dataset(informative=True)
    cfg = _cfg(exogenous="choose", prior_choice=True, members=2, member_workers=1)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    training = ck["metrics"]["training"]
    assert training["exogenous"]["kept"] is True, training["exogenous"]["why"]
    kinds = training["kinds"]
    assert set(kinds) >= {"candidates", "chosen", "why", "val_theta_rmse_prior"}
    for d in ("ignore/member_0", "member_0", "member_1", "prior/member_0"):
        assert (tmp_path / "m" / d / "best.pt").is_file()
    prior = load_checkpoint(tmp_path / "m" / "prior" / "member_0" / "best.pt")
    assert prior.net.prior is not None and prior.train_config["exogenous"] == "use"
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    model_kind = {0: "plain", 1: "prior"}.get(len(kinds["chosen"]), "composite")
    assert [r["kind"] for r in rows] == ["plain", "plain", "prior", model_kind]
    assert _gear_effect(best) > 1e-3  # whichever kind drives the joint reads the gear
    notes = tomllib.loads((tmp_path / "m" / "config.toml").read_text())
    assert notes["exogenous"]["kept"] is True and "chosen" in notes["kinds"]
