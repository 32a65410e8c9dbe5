"""What an exported ONNX surrogate is (``exsur info model.onnx``): its graph's inputs and
outputs, the exsur metadata a runtime needs, and the checkpoint's own description.

An integrator wiring the graph into a controller (C++, a PLC, another language's runtime)
needs the names, shapes and units of every input and output and how the model steps; all of
it travels in the file (:mod:`.export`).  The checkpoint's card (training, validation
scores, notes) travels as ``exsur_card``; a file exported before it has the rest.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ..errors import CheckpointError
from ..evaluate.card import card_markdown, machine_phrase, public


def onnx_card(path: str | Path) -> dict[str, Any]:
    """The description of the exported surrogate at ``path``.

    Returns:
        ``file`` (path, bytes, producer, opset), ``graph`` (``inputs`` / ``outputs``: name,
        element type, shape with ``n_batch`` for the dynamic axis), ``metadata`` (the exsur
        keys, JSON values parsed) and ``card`` (the checkpoint's card, or None for a file
        exported without one).

    Raises:
        CheckpointError: a missing, unreadable or foreign file (one line naming it).
    """
    try:
        import onnx
    except ImportError as e:  # pragma: no cover - the export extra
        raise CheckpointError(
            f"{path}: reading ONNX files needs the onnx package (pip install "
            "'excavator-surrogate[export]')"
        ) from e
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: ONNX file not found (write one with 'exsur export')")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as e:  # protobuf raises several types
        raise CheckpointError(
            f"{path}: not a readable ONNX file ({type(e).__name__}); export it again"
        ) from e
    meta = {p.key: p.value for p in model.metadata_props}
    if "exsur_spec" not in meta:
        raise CheckpointError(f"{path}: not an exsur export (no exsur_spec metadata)")
    parsed: dict[str, Any] = {}
    for k, v in meta.items():
        if k == "exsur_card":
            continue
        try:
            parsed[k] = json.loads(v)
        except ValueError:
            parsed[k] = v
    card = json.loads(meta["exsur_card"]) if "exsur_card" in meta else None
    opset = next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), None)
    return {
        "file": {
            "path": str(path),
            "bytes": path.stat().st_size,
            "producer": model.producer_name,
            "opset": opset,
        },
        "graph": {
            "inputs": [_value(v) for v in model.graph.input],
            "outputs": [_value(v) for v in model.graph.output],
        },
        "metadata": parsed,
        "card": card,
    }


BATCH_SYMBOL = "batch"
"""The exporter's name of the dynamic batch axis (``n_batch`` on the card)."""


def _value(v: Any) -> dict[str, Any]:
    """A graph input or output: name, element type (NumPy's name for it, as onnx maps it) and
    shape (``n_batch``: the batch axis; any other symbolic axis by its own name, ``?``
    unnamed)."""
    from onnx.helper import tensor_dtype_to_np_dtype

    t = v.type.tensor_type
    dims = []
    for d in t.shape.dim:
        if d.HasField("dim_value"):
            dims.append(int(d.dim_value))
        else:
            sym = d.dim_param
            dims.append("n_batch" if sym == BATCH_SYMBOL else sym or "?")
    kind = tensor_dtype_to_np_dtype(t.elem_type).name
    return {"name": v.name, "type": kind, "shape": dims}


def onnx_card_json(card: dict[str, Any]) -> dict[str, Any]:
    """``card`` for ``--json``: the embedded checkpoint card without its raw training record."""
    return {**card, "card": public(card["card"]) if card["card"] else None}


def onnx_card_markdown(card: dict[str, Any]) -> str:
    """The card of :func:`onnx_card` as Markdown (what ``exsur info model.onnx`` prints).

    The checkpoint's card is told about the graph: it runs in the graph's mode (a stateful
    checkpoint exported windowed takes a window a call), and a last line says which of the
    card's bands and flags the graph carries as outputs."""
    f, meta = card["file"], card["metadata"]
    mode = meta.get("exsur_mode", "?")
    step = (
        "one step a call, the recurrent state as inputs and outputs"
        if mode == "stateful"
        else f"a window of {meta.get('exsur_window', '?')} samples a call"
    )
    spec = meta.get("exsur_spec") or {}
    machine = {
        "name": spec.get("name", "?"),
        "class": (spec.get("meta") or {}).get("class"),
        "data_source": (spec.get("meta") or {}).get("data_source"),
        "rate_hz": spec.get("rate_hz", 0.0),
    }
    head = [
        f"# {f['path']}",
        "",
        machine_phrase(machine) + f", exported to ONNX (opset {f['opset']}, {mode}: {step}); "
        f"{f['bytes'] / 1e6:.1f} MB.",
        "",
        "## Graph",
        "",
        "| | Name | Type | Shape |",
        "|---|---|---|---|",
    ]
    for kind in ("inputs", "outputs"):
        for k, v in enumerate(card["graph"][kind]):
            shape = "(" + ", ".join(str(d) for d in v["shape"]) + ")"
            label = kind[:-1] if k == 0 else ""
            head.append(f"| {label} | `{v['name']}` | {v['type']} | {shape} |")
    units = meta.get("exsur_units") or {}
    if units:
        head += [
            "",
            "Units: "
            + "; ".join(f"{n} θ in {u['theta']}, ω in {u['omega']}" for n, u in units.items())
            + f". Sample period {meta.get('exsur_dt', '?')} s. The module docstring of "
            "`excavator_surrogate.env.export` describes every input and output; "
            "`excavator_surrogate.env.onnx_stepper.OnnxStepper` steps it in closed loop.",
        ]
    if card["card"] is None:
        return (
            "\n".join([*head, "", "No checkpoint card in this file (exported before it)."]) + "\n"
        )
    ckpt = card["card"]
    graph_card = {**ckpt, "network": {**ckpt["network"], "mode": mode}}
    return card_markdown(graph_card, header=head) + _graph_uncertainty(meta, ckpt) + "\n"


def _graph_uncertainty(meta: dict[str, Any], ckpt: dict[str, Any]) -> str:
    """One line: what of the checkpoint's uncertainty this graph outputs (``exsur_members``,
    ``exsur_ood``); the card above describes the checkpoint, which may have more."""
    n_member = int(meta.get("exsur_members") or 0)
    ood = str(meta.get("exsur_ood", "0")) == "1"
    spread = f"`omega_members` ({n_member} members; their spread is the uncertainty)"
    if n_member and ood:
        return f"This graph outputs both: {spread} and `ood` (the flags)."
    if n_member:
        return f"This graph outputs {spread} but no `ood`: it flags nothing."
    how = (
        "export again with `--uncertainty` (stateful) for them"
        if int(ckpt["network"].get("n_member") or 1) > 1
        else "a single network cannot export them (`--uncertainty` needs an ensemble)"
    )
    return f"This graph outputs no bands or flags (no `omega_members` or `ood`): {how}."
