"""Exogenous inputs must not hurt: ``exogenous = "ignore"`` and ``"choose"``."""

from __future__ import annotations

import csv
import math
import tomllib
from dataclasses import replace

import numpy as np
import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.data.episode import Episode
from excavator_surrogate.spec import InputSpec, JointSpec, MachineSpec
from excavator_surrogate.surrogate.checkpoint import load_checkpoint, read_checkpoint
from excavator_surrogate.training import train
from excavator_surrogate.training.batches import split_episodes
from excavator_surrogate.training.variants import trial_reaches_no_joint
from tests.helpers.surrogates import teacher_forced_omega
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
    kw = {"epochs": 6, **kw}
    return tiny_train_config(
        window=5, hidden=12, head_hidden=12, seq_len=40, burn_in=5, lr=1e-2, **kw
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


@pytest.mark.parametrize("per_joint", [True, False])
def test_choose_with_the_kind_choice_keeps_the_map_correcting_networks_blind(
    tmp_path, caplog, per_joint
):
    """The inputs are chosen first; the rest of the plain ensemble then trains the chosen
    way, the map-correcting networks ignore the inputs whichever way won, and the kind
    choice runs on them: a joint they drive never reads the gear.  Without the per-joint
    route the trial can reach no joint here, and the run warns."""
    ds = _dataset(informative=True)
    cfg = _cfg(
        exogenous="choose",
        prior_choice=True,
        members=2,
        member_workers=1,
        inputs_per_joint=per_joint,
    )
    with caplog.at_level("WARNING", logger="excavator_surrogate"):
        best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    warned = [r.getMessage() for r in caplog.records if "decides no joint" in r.getMessage()]
    assert len(warned) == (not per_joint)
    ck = read_checkpoint(best)
    training = ck["metrics"]["training"]
    kinds = training["kinds"]
    assert set(kinds) >= {"candidates", "chosen", "why", "val_theta_rmse_prior"}
    for d in ("ignore/member_0", "member_0", "member_1", "prior/member_0"):  # "use" won
        assert (tmp_path / "m" / d / "best.pt").is_file()
    prior = load_checkpoint(tmp_path / "m" / "prior" / "member_0" / "best.pt")
    assert prior.net.prior is not None and prior.train_config["exogenous"] == "ignore"
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    model_kind = {0: "plain", 1: "prior"}.get(len(kinds["chosen"]), "composite")
    assert [r["kind"] for r in rows] == ["plain", "plain", "prior", model_kind]
    assert _gear_effect(tmp_path / "m" / "prior" / "member_0" / "best.pt") == 0.0
    assert _gear_effect(tmp_path / "m" / "member_1" / "best.pt") > 1e-3  # the chosen way
    # the joint reads the gear exactly where the plain networks drive it, and the record
    # (the report's line, config.toml) says so
    reads = _gear_effect(best) > 1e-3
    assert reads == (model_kind == "plain")
    record = training["exogenous"]
    assert record["kept"] is reads and record["joints"] == (["boom"] if reads else [])
    assert reads or record["why"].endswith("drive boom: no joint reads them")
    notes = tomllib.loads((tmp_path / "m" / "config.toml").read_text())
    assert notes["exogenous"]["kept"] is reads and "chosen" in notes["kinds"]


@pytest.mark.parametrize("per_joint", [True, False])
def test_a_trial_that_can_reach_no_joint_says_so(tmp_path, per_joint):
    """Validation spans the joint's commands, so the blind map-correcting networks drive it:
    the whole-way choice reaches no joint, and without the per-joint route (or with no pair
    count fitting) neither does the trial."""
    ds = _dataset(informative=True)
    _, val = split_episodes(_cfg(), ds)
    cfg = _cfg(exogenous="choose", prior_choice=True, members=2, inputs_per_joint=per_joint)
    assert trial_reaches_no_joint(cfg, ds, val, half=1, n_prior=1) is not per_joint
    assert trial_reaches_no_joint(cfg, ds, val, half=1, n_prior=2)  # 2 cannot divide 1 pair
    assert not trial_reaches_no_joint(cfg, ds, val, half=1, n_prior=0)  # plain networks drive
    by_val = replace(cfg, prior_drive="validation")
    assert not trial_reaches_no_joint(by_val, ds, val, half=1, n_prior=1)
    narrow = replace(cfg, choice_min_span=1.0)  # no validation spans all of its training's
    assert not trial_reaches_no_joint(narrow, ds, val, half=1, n_prior=1)


SPEC2 = MachineSpec(
    joints=(
        JointSpec("boom", theta_min=-1.2, theta_max=1.2),
        JointSpec("arm", theta_min=-1.2, theta_max=1.2),
    ),
    rate_hz=20.0,
    name="gear-2j",
    inputs=(InputSpec("gear", u_min=-1.0, u_max=1.0),),
)


def _episode2(seed: int, n_step: int = 200) -> Episode:
    """Two joints driven by sine commands; the ``gear`` adds to the boom's speed only."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_step) / SPEC2.rate_hz
    cmd = 0.8 * np.sin(
        2 * math.pi * rng.uniform(0.1, 0.3, 2)[None] * t[:, None] + rng.uniform(0, 6.3, 2)[None]
    )
    gear = np.repeat(rng.choice([-1.0, 1.0], n_step // 40 + 1), 40)[:n_step]
    speed = 0.5 * cmd + np.stack([0.3 * gear, 0.0 * gear], axis=1)
    theta = np.zeros((n_step, 2))
    for k in range(1, n_step):
        theta[k] = np.clip(theta[k - 1] + speed[k - 1] / SPEC2.rate_hz, -1.1, 1.1)
    omega = np.concatenate([np.zeros((1, 2)), np.diff(theta, axis=0) * SPEC2.rate_hz])
    return Episode(
        spec=SPEC2,
        time=t,
        u=np.concatenate([cmd, gear[:, None]], axis=1),
        theta=theta,
        omega=omega,
        name=f"ep{seed}",
    )


def _dataset2() -> Dataset:
    ds = Dataset(spec=SPEC2)
    ds.episodes["train"] = [_episode2(s) for s in range(4)]
    ds.episodes["val"] = [_episode2(50)]
    return ds


def _omega(sur, ep: Episode, *, flip_gear: bool = False) -> torch.Tensor:
    """The net's normalised one-step outputs on ``ep`` (teacher-forced), the gear flipped or not."""
    u = ep.u * np.array([1.0, 1.0, -1.0 if flip_gear else 1.0])
    x = sur.norm.encode(
        torch.tensor(ep.theta, dtype=torch.float32), torch.tensor(u.astype(np.float32))
    )
    with torch.no_grad():
        y, _ = sur.net.forward_seq(x[None])  # (1, n_step, n_joint), the state
    return y[0]


def test_paired_takes_each_joint_from_its_way_and_averages_the_seeds(tmp_path):
    from excavator_surrogate.training.input_choice import paired

    ds = _dataset2()
    nets = {
        (w, s): load_checkpoint(
            train(
                _cfg(exogenous=w, seed=s),
                ds,
                out=tmp_path / f"{w}{s}",
                show_progress=False,
            )
        )
        for w in ("use", "ignore")
        for s in (0, 1)
    }
    use, ignore = [nets["use", s] for s in (0, 1)], [nets["ignore", s] for s in (0, 1)]
    model = paired(use, ignore, [True, False])
    ep = _episode2(9)
    got = _omega(model, ep)
    # the plain loop: joint 0 is the mean of the networks that use the gear, joint 1 of the others
    want = torch.stack(
        [
            torch.stack([_omega(n, ep)[:, 0] for n in use]).mean(0),
            torch.stack([_omega(n, ep)[:, 1] for n in ignore]).mean(0),
        ],
        dim=-1,
    )
    torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)
    # the arm comes from networks that cannot read the gear: flipping it cannot move the arm
    flipped = _omega(model, ep, flip_gear=True)
    assert torch.equal(flipped[:, 1], got[:, 1])
    assert float((flipped[:, 0] - got[:, 0]).abs().max()) > 1e-3
    assert (model.metrics or {}).get("ensemble", {}).get("n_member") == 2
    with pytest.raises(ValueError, match="do not pair up"):
        paired(use, ignore[:1], [True, False])


def test_choose_gives_the_inputs_to_the_joints_they_help(tmp_path, monkeypatch):
    """The whole half that uses the gear is refused (forced here); the boom, where it helps,
    takes it alone: the model pairs each seed's two networks, and the rest of the budget
    trains one more pair."""
    from excavator_surrogate.training import input_choice

    calls: list = []

    def rule(use, ignore):  # the whole half refused, the sets judged as usual
        calls.append(use)
        return (False, "refused (test)") if len(calls) == 1 else (True, "kept")

    monkeypatch.setattr(input_choice, "choose_inputs", rule)
    monkeypatch.setattr(input_choice, "input_joints", lambda use, ignore: [True, False])
    ds = _dataset2()
    cfg = _cfg(exogenous="choose", members=4, member_workers=1)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    record = ck["metrics"]["training"]["exogenous"]
    assert record["kept"] and record["per_joint"] and record["joints"] == ["boom"]
    assert [t["joints"] for t in record["tried"]] == [["boom"]] and "boom take" in record["why"]
    assert ck["train_config"]["exogenous"] == "use"
    for w in ("use", "ignore"):
        for i in range(3):  # 2 + 2 for the choice, then one more pair
            assert (tmp_path / "m" / w / f"member_{i}" / "best.pt").is_file()
    assert not (tmp_path / "m" / "member_0").exists()
    rows = list(csv.DictReader((tmp_path / "m" / "log.csv").open()))
    assert [r["exogenous"] for r in rows] == ["use"] * 3 + ["ignore"] * 3 + ["per joint"]
    model = load_checkpoint(best)
    ep = _episode2(9)
    use = [load_checkpoint(tmp_path / "m" / "use" / f"member_{i}" / "best.pt") for i in range(3)]
    ign = [load_checkpoint(tmp_path / "m" / "ignore" / f"member_{i}" / "best.pt") for i in range(3)]
    want = torch.stack(
        [
            torch.stack([_omega(n, ep)[:, 0] for n in use]).mean(0),
            torch.stack([_omega(n, ep)[:, 1] for n in ign]).mean(0),
        ],
        dim=-1,
    )
    torch.testing.assert_close(_omega(model, ep), want, rtol=1e-4, atol=1e-5)
    notes = tomllib.loads((tmp_path / "m" / "config.toml").read_text())
    assert notes["exogenous"]["joints"] == ["boom"]


def test_the_inputs_per_joint_with_the_kind_choice(tmp_path, monkeypatch):
    """As above with ``prior_choice``: the choice's two pairs and two map-correcting networks
    that ignore the gear (they must divide the pairs: the pair planned after them is not
    trained); the kinds are chosen with the pairs as the plain side, and the model is, joint
    by joint, the chosen share of the map-correcting networks' mean plus the rest from the
    networks of the joint's way (the plain loop over the saved networks)."""
    from excavator_surrogate.training import input_choice

    calls: list = []

    def rule(use, ignore):
        calls.append(use)
        return (False, "refused (test)") if len(calls) == 1 else (True, "kept")

    monkeypatch.setattr(input_choice, "choose_inputs", rule)
    monkeypatch.setattr(input_choice, "input_joints", lambda use, ignore: [True, False])
    ds = _dataset2()
    cfg = _cfg(exogenous="choose", prior_choice=True, members=4, member_workers=1)
    best = train(cfg, ds, out=tmp_path / "m", show_progress=False)
    ck = read_checkpoint(best)
    training = ck["metrics"]["training"]
    kinds = training["kinds"]
    assert set(kinds) >= {"candidates", "chosen", "weights", "why"}
    exo = training["exogenous"]  # the boom reads the gear unless the kinds took it wholly
    reads = kinds["weights"][0] < 1.0
    assert exo["per_joint"] and exo["joints"] == (["boom"] if reads else [])
    assert exo["kept"] is reads
    m = tmp_path / "m"
    for d in ("use", "ignore", "prior"):
        assert sorted(p.name for p in (m / d).iterdir()) == ["member_0", "member_1"]
    rows = list(csv.DictReader((m / "log.csv").open()))
    assert [r["exogenous"] for r in rows] == (
        ["use"] * 2 + ["ignore"] * 2 + ["ignore (map-correcting)"] * 2 + ["per joint"]
    )
    nets = {
        d: [load_checkpoint(m / d / f"member_{i}" / "best.pt") for i in (0, 1)]
        for d in ("use", "ignore", "prior")
    }
    assert all(n.train_config["exogenous"] == "ignore" for n in nets["prior"])
    ep = _episode2(9)

    def mean(d: str, j: int) -> torch.Tensor:  # in rad/s: the kinds normalise differently
        return torch.stack([teacher_forced_omega(n, ep)[:, j] for n in nets[d]]).mean(0)

    a = kinds["weights"]
    want = torch.stack(
        [
            a[j] * mean("prior", j) + (1 - a[j]) * mean("use" if j == 0 else "ignore", j)
            for j in (0, 1)
        ],
        dim=-1,
    )
    torch.testing.assert_close(
        teacher_forced_omega(load_checkpoint(best), ep), want, rtol=1e-4, atol=1e-5
    )


def _without_gear(ds: Dataset) -> Dataset:
    spec = MachineSpec(joints=SPEC.joints, rate_hz=SPEC.rate_hz, name=SPEC.name)
    out = Dataset(spec=spec)
    for split, eps in ds.episodes.items():
        out.episodes[split] = [e.replace(spec=spec, u=e.u[:, :1]) for e in eps]
    return out


@pytest.mark.parametrize("prior", [False, True])
def test_a_network_that_ignores_its_inputs_trains_as_one_without_them(tmp_path, prior) -> None:
    """A held gear column (1 everywhere) and ``exogenous = "ignore"``: the network trains on
    the data without the column, so it is the one trained on a dataset that never had it,
    bit for bit (same shapes, same kernels), plain or map-correcting; its checkpoint holds
    the gear's column with zero weights."""
    with_gear = _dataset(informative=False)
    for eps in with_gear.episodes.values():
        for e in eps:
            e.u[:, 1] = 1.0
    cfg = _cfg(members=1, exogenous="ignore", prior=prior, seed=3)
    got = load_checkpoint(train(cfg, with_gear, out=tmp_path / "gear", show_progress=False))
    ref = load_checkpoint(
        train(cfg, _without_gear(with_gear), out=tmp_path / "none", show_progress=False)
    )
    assert got.spec.u_names == ("boom", "gear") and ref.spec.u_names == ("boom",)
    w_got = dict(got.net.named_parameters())
    for name, w in ref.net.named_parameters():
        if name == "rnn.weight_ih_l0":
            assert torch.all(w_got[name][:, 1 + 1] == 0)  # theta, u_boom, then the gear
            kept = torch.cat([w_got[name][:, :2], w_got[name][:, 3:]], 1)
            assert torch.equal(kept, w)
        else:
            assert torch.equal(w_got[name], w), name
    assert torch.equal(torch.cat([got.norm.x_mean[:2], got.norm.x_mean[3:]]), ref.norm.x_mean)
    ep = with_gear.val[0]
    ref_ep = _without_gear(with_gear).val[0]
    torch.testing.assert_close(  # wider sums: equal up to their order
        teacher_forced_omega(got, ep), teacher_forced_omega(ref, ref_ep), rtol=1e-5, atol=1e-6
    )


def test_a_run_that_ignores_its_inputs_resumes_from_its_stored_checkpoint(tmp_path) -> None:
    """The checkpoints hold the inputs' columns (zero weights), the training runs without
    them: a resumed run takes them away again and stores them again."""
    ds = _dataset(informative=True)
    out = tmp_path / "i"
    train(_cfg(members=1, exogenous="ignore", epochs=2), ds, out=out, show_progress=False)
    assert load_checkpoint(out / "last.pt").spec.u_names == ("boom", "gear")
    cfg = _cfg(members=1, exogenous="ignore", epochs=4)
    best = train(cfg, ds, out=out, resume=out / "last.pt", show_progress=False)
    assert [h["epoch"] for h in read_checkpoint(out / "last.pt")["history"]] == [0, 1, 2, 3]
    assert _gear_effect(best) == 0.0 and load_checkpoint(best).spec.u_names == ("boom", "gear")


def test_the_record_of_the_input_and_kind_choices_loads_back_as_its_preset(tmp_path):
    """A run that chose its inputs and its kinds records ``[exogenous]`` and ``[kinds]`` in
    ``config.toml``; the record loads back as ``--preset`` to the config it ran with (it was
    refused: "unknown table [kinds]")."""
    from excavator_surrogate.stages import build_configs, load_preset

    cfg = _cfg(exogenous="choose", prior_choice=True, members=2, member_workers=1, epochs=2)
    train(cfg, _dataset(informative=True), out=tmp_path / "m", show_progress=False)
    record = tmp_path / "m" / "config.toml"
    assert {"exogenous", "kinds"} <= set(tomllib.loads(record.read_text()))
    assert build_configs(load_preset(record), sections=["train"])["train"] == cfg
