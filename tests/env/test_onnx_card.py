"""exsur info model.onnx: an exported surrogate's graph, units and checkpoint card read back.

The card does not depend on the exporter except for the graph's shapes, which the first test
and the state width's test check on dynamo's graphs (the default exporter); the others export
with torchscript (0.1-1 s against dynamo's 3-9 s on a slow computer).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import onnx
import pytest

from excavator_surrogate.cli import main
from excavator_surrogate.env import export_onnx
from excavator_surrogate.env.onnx_card import onnx_card, onnx_card_json, onnx_card_markdown
from excavator_surrogate.errors import CheckpointError
from excavator_surrogate.evaluate.card import card_markdown, model_card, public
from excavator_surrogate.spec import JointSpec, MachineSpec
from excavator_surrogate.surrogate.checkpoint import save_checkpoint
from excavator_surrogate.surrogate.coverage import CoverageRecord, channel_names
from excavator_surrogate.surrogate.ensemble import merge
from tests.helpers.surrogates import tiny_surrogate


def _described(spec: MachineSpec | None = None, *, mode: str = "stateful"):
    """A tiny surrogate with the training record and validation scores a card reads."""
    sur = tiny_surrogate(spec, mode=mode, hidden=8) if spec else tiny_surrogate(mode=mode)
    n = len(sur.spec.names)
    sur.train_config = {"seed": 4, "epochs": 9, "feedback": "free"}
    sur.metrics = {
        "val": {
            "theta_r2": [0.99] * (n - 1) + [0.5],
            "theta_rmse": [math.pi / 180.0] * n,
            "omega_rmse": [0.01] * n,
        },
        "training": {
            "epochs_planned": 9,
            "epochs_done": 4,
            "stopped": "budget",
            "budget_cut": True,
            "max_train_seconds": 20.0,
        },
    }
    return sur


@pytest.mark.parametrize("mode", ["stateful", "windowed"])
def test_an_export_carries_its_checkpoint_card_and_describes_its_graph(
    mode: str, tmp_path: Path
) -> None:
    sur = _described(mode=mode)
    ckpt = save_checkpoint(tmp_path / "best.pt", sur)
    path = export_onnx(ckpt, tmp_path / "model.onnx")
    card = onnx_card(path)
    model = onnx.load(str(path))
    # the graph, as onnx itself lists it, with the batch axis named
    assert [v["name"] for v in card["graph"]["inputs"]] == [i.name for i in model.graph.input]
    assert [v["name"] for v in card["graph"]["outputs"]] == [o.name for o in model.graph.output]
    theta = card["graph"]["inputs"][0]
    assert theta["name"] == "theta" and theta["type"] == "float32"
    window = [] if mode == "stateful" else [sur.model_cfg.window]  # windowed: W samples a call
    assert theta["shape"] == ["n_batch", *window, len(sur.spec.names)]
    assert card["file"]["opset"] == 18 and card["file"]["bytes"] == path.stat().st_size
    assert card["metadata"]["exsur_mode"] == mode
    # the embedded card is the checkpoint's, but for its file entry
    from_ckpt = model_card(ckpt)
    from_ckpt.pop("file")
    assert card["card"] == json.loads(json.dumps(from_ckpt, allow_nan=False))
    text = onnx_card_markdown(card)
    assert text.startswith(f"# {path}\n")
    assert f"exported to ONNX (opset 18, {mode}" in text
    shape = "(n_batch, 4)" if mode == "stateful" else f"(n_batch, {window[0]}, 4)"
    assert f"| input | `theta` | float32 | {shape} |" in text
    assert "| output | `omega` | float32 | (n_batch, 4) |" in text
    assert "swing θ in rad, ω in rad/s" in text
    # below the header, the same card `exsur info best.pt` prints
    ckpt_text = card_markdown(model_card(ckpt))
    body = ckpt_text[ckpt_text.index("## Machine") :]
    last = "This graph outputs no bands or flags (no `omega_members` or `ood`): a single network"
    assert text.startswith(body, text.index("## Machine")) and text.split("\n")[-2].startswith(last)
    assert "**Warning: the wall-time cap cut training short**" in text
    assert "Seed 4" in text
    assert card["card"]["training"]["pace"] is None  # no training log beside the checkpoint
    if mode == "stateful":  # with one, the export carries how fast it trained, as the card
        (tmp_path / "log.csv").write_text("epoch,time_s,epoch_s,val_s,ref_epoch_s\n0,5,4,1,\n")
        again = onnx_card(export_onnx(ckpt, tmp_path / "again.onnx", exporter="torchscript"))
        assert again["card"]["training"]["pace"]["epochs"] == 1
        assert "Time on this computer: 1 network(s), 1 epochs in all" in onnx_card_markdown(again)


def test_the_card_of_an_export_states_the_graph_mode_and_outputs(tmp_path: Path) -> None:
    """The card said a windowed graph of a stateful checkpoint "Runs stateful", and that an
    export without the uncertainty outputs flags OOD steps; it now states the graph's mode
    and what of the checkpoint's bands and flags the graph outputs."""
    ens = merge([tiny_surrogate(seed=s, hidden=8) for s in range(2)])
    n_j = ens.spec.n_joint
    lo = np.concatenate([np.full(n_j, -1000.0), [-7.0, -1.0, 0.0, -1.0], np.full(n_j, -1.0)])
    hi = -lo + np.concatenate([np.zeros(n_j), [0.0, 0.0, 3.0, 0.0], np.zeros(n_j)])
    grid = np.ones((n_j, 10, 10), dtype=np.int64)
    rec = CoverageRecord(channel_names(ens.spec), lo, hi, grid, n_sample=500)
    ens.metrics["coverage"] = rec.to_dict()  # beside the ensemble's own record
    ckpt = save_checkpoint(tmp_path / "ens.pt", ens)

    def text(name: str, **kw) -> str:
        return onnx_card_markdown(onnx_card(export_onnx(ckpt, tmp_path / name, **kw)))

    windowed = text("w.onnx", mode="windowed", exporter="torchscript")
    assert (
        "- Runs windowed: a fresh state per window" in windowed and "Runs stateful" not in windowed
    )
    assert "free runs flag the steps outside the training data" in windowed  # the checkpoint
    no = "This graph outputs no bands or flags (no `omega_members` or `ood`): export again with "
    assert windowed.endswith(no + "`--uncertainty` (stateful) for them.\n")
    plain = text("p.onnx", exporter="torchscript")
    assert "- Runs stateful: the state is carried" in plain and plain.endswith("for them.\n")
    both = text("u.onnx", exporter="torchscript", uncertainty=True)
    assert both.endswith(
        "This graph outputs both: `omega_members` (2 members; their spread is the "
        "uncertainty) and `ood` (the flags).\n"
    )
    del ens.metrics["coverage"]
    bare = save_checkpoint(tmp_path / "bare.pt", ens)
    card = onnx_card(
        export_onnx(bare, tmp_path / "b.onnx", exporter="torchscript", uncertainty=True)
    )
    assert onnx_card_markdown(card).endswith("but no `ood`: it flags nothing.\n")


def test_linear_joints_are_named_in_their_own_unit(tmp_path: Path) -> None:
    spec = MachineSpec(
        (
            JointSpec("swing", periodic=True),
            JointSpec("boom", kind="linear", unit="mm", theta_min=0.1, theta_max=1.6),
        ),
        name="stroke-rig",
    )
    path = export_onnx(_described(spec), tmp_path / "m.onnx", exporter="torchscript")
    text = onnx_card_markdown(onnx_card(path))
    assert "A surrogate of **stroke-rig**" in text
    assert "boom θ in m, ω in m/s" in text  # the graph's own unit (SI)
    assert "| boom | linear | 100.0 … 1600.0 mm |" in text  # the card's display unit


@pytest.mark.parametrize("exporter", ["torchscript", "dynamo"])
def test_the_state_width_is_shown_as_its_size(exporter: str, tmp_path: Path) -> None:
    """``h_out`` / ``c_out`` are (n_layer, n_batch, hidden) with either exporter (torchscript
    had left the width symbolic, which the card printed as ``n_batch``)."""
    sur = _described()
    cfg = sur.model_cfg
    path = export_onnx(sur, tmp_path / "m.onnx", exporter=exporter)
    shapes = {v["name"]: v["shape"] for v in onnx_card(path)["graph"]["outputs"]}
    want = [cfg.n_layer, "n_batch", cfg.hidden]
    assert shapes["h_out"] == want and shapes["c_out"] == want
    text = onnx_card_markdown(onnx_card(path))
    assert f"| `h_out` | float32 | ({cfg.n_layer}, n_batch, {cfg.hidden}) |" in text
    # a file of another writer: a symbolic axis other than the batch keeps its own name
    model = onnx.load(str(path))
    model.graph.output[2].type.tensor_type.shape.dim[2].dim_param = "width"
    onnx.save(model, str(tmp_path / "other.onnx"))
    shapes = {v["name"]: v["shape"] for v in onnx_card(tmp_path / "other.onnx")["graph"]["outputs"]}
    assert shapes["h_out"] == [cfg.n_layer, "n_batch", "width"]


def test_an_export_without_a_card_still_describes_its_graph(tmp_path: Path) -> None:
    path = export_onnx(_described(), tmp_path / "model.onnx", exporter="torchscript")
    model = onnx.load(str(path))
    keep = [p for p in model.metadata_props if p.key != "exsur_card"]
    del model.metadata_props[:]
    model.metadata_props.extend(keep)
    old = tmp_path / "old.onnx"
    onnx.save(model, str(old))
    card = onnx_card(old)
    assert card["card"] is None and card["metadata"]["exsur_mode"] == "stateful"
    text = onnx_card_markdown(card)
    assert "## Graph" in text and "No checkpoint card in this file" in text
    assert onnx_card_json(card)["card"] is None


def test_exsur_info_on_an_export_prints_text_or_json_and_refuses_bad_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ckpt = save_checkpoint(tmp_path / "best.pt", _described())
    path = tmp_path / "model.onnx"
    argv = ["export", str(ckpt), "--out", str(path), "--no-verify", "--exporter", "torchscript"]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["info", str(path)]) == 0
    assert capsys.readouterr().out == onnx_card_markdown(onnx_card(path))
    assert main(["info", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["graph"] == onnx_card(path)["graph"]
    assert got["card"] == json.loads(json.dumps(public(onnx_card(path)["card"])))
    assert "_training_record" not in got["card"]
    # one line, exit code 2: a corrupt file, a foreign ONNX graph
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00\x01 not protobuf at all")
    assert main(["info", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}: not a readable ONNX file" in err[0]
    foreign = onnx.load(str(path))
    del foreign.metadata_props[:]
    other = tmp_path / "other.onnx"
    onnx.save(foreign, str(other))
    assert main(["info", str(other)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not an exsur export" in err[0]
    with pytest.raises(CheckpointError, match="ONNX file not found"):
        onnx_card(tmp_path / "missing.onnx")
