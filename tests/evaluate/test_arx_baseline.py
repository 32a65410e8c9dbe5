"""The evaluation's ARX baseline is ARX on every joint, whatever the surrogate's map joints."""

from __future__ import annotations

from excavator_surrogate.data import write_dataset
from excavator_surrogate.data.dataset import load_dataset
from excavator_surrogate.evaluate.cbe import evaluate_checkpoint, evaluate_models
from excavator_surrogate.spec import EXCAVATOR
from excavator_surrogate.surrogate.baselines import fit_arx
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.synthetic import synthetic_split
from tests.helpers.surrogates import PARALLEL_JOINTS, on_parallel_map, tiny_surrogate


def test_the_arx_baseline_does_not_follow_the_surrogates_static_map(tmp_path):
    items = synthetic_split(EXCAVATOR, n_train=3, n_val=1, n_test=1, n_step=200, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    sur = on_parallel_map(tiny_surrogate(mode="stateful", window=5))
    assert sur.norm.own is not None  # the swing and the bucket follow a map in parallel
    ckpt = save_checkpoint(tmp_path / "m.pt", sur)
    res = evaluate_checkpoint(ckpt, ds, out=tmp_path / "ev", figure=False)
    got = res["compare"]["ARX"]["theta"]
    # the same as an ARX fitted on the surrogate's features without its map joints
    arx = fit_arx(
        ds.train,
        window=sur.window,
        spec=sur.spec,
        norm=sur.norm.with_own(None),
        val=ds.val,
        end_stops=sur.end_stops,
    )
    assert arx.norm.own is None
    alone, _ = evaluate_models({"arx": arx}, ds.test)
    for j in ds.spec.names:
        assert got[j]["rmse"] == alone["arx"]["theta"][j]["rmse"], j
    # and not the map's on the map joints (before, it ran them on the surrogate's map)
    for j, on_map in zip(ds.spec.names, PARALLEL_JOINTS):
        if on_map:
            assert got[j]["rmse"] != res["theta"][j]["rmse"], j


def test_the_baselines_run_in_the_checkpoints_envelope(tmp_path):
    """A dataset that declares no limits: training fills the end stops and speed bounds in
    from its data and stores them in the checkpoint's spec.  The baselines read the
    dataset's spec before, so the ARX had no envelope at all (a boom at 3818 degrees after
    a held command) and the structured model no speed bound."""
    import dataclasses

    import numpy as np

    from excavator_surrogate.evaluate.cbe import baselines
    from excavator_surrogate.surrogate.envelope import fill_envelope

    bare = dataclasses.replace(
        EXCAVATOR,
        joints=tuple(
            dataclasses.replace(j, theta_min=None, theta_max=None, omega_max=None)
            for j in EXCAVATOR.joints
        ),
    )
    items = synthetic_split(bare, n_train=3, n_val=1, n_test=1, n_step=200, noise=0.001)
    ds = load_dataset(write_dataset(tmp_path / "data", items))
    filled, _ = fill_envelope(ds.spec, ds.train, limit_margin=0.0, speed_margin=0.1)
    sur = tiny_surrogate(filled, end_stops=True)
    assert sur.limits_np() is not None and np.isfinite(sur.limits_np()[2]).all()
    models = baselines(sur, ds)
    assert set(models) == {"ARX", "Structured"}
    for name, model in models.items():
        for got, want in zip(model.limits_np(), sur.limits_np(), strict=True):
            np.testing.assert_array_equal(got, want, err_msg=name)
