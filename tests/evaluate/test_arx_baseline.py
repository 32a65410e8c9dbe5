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
        spec=ds.spec,
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
