"""ONNX export of the single-step surrogate and an onnxruntime stepper.

Stateful export (LSTM/GRU checkpoints, the default): the graph is :class:`~.fused.FusedStep`,
i.e. the feature encoding and the normalisation are folded into the weights, and the
recurrent state is explicit:

=========  =============================  ==========================================
name       shape                          meaning
=========  =============================  ==========================================
inputs
``theta``  (n_batch, n_joint) float32     angles θ[k] in rad
``u``      (n_batch, n_u) float32         commands u[k]: joints', then inputs'
``h``      (n_layer, n_batch, hidden)     recurrent state h
``c``      (n_layer, n_batch, hidden)     LSTM cell state c (passed through for GRU)
outputs
``omega``  (n_batch, n_joint) float32     ω̂[k+1] in rad/s
``theta_next``  (n_batch, n_joint)        θ[k] + T_s·ω̂[k+1] in rad
``h_out``, ``c_out``                      new state
=========  =============================  ==========================================

A surrogate with Q > 0 command play features (``TrainConfig.play``) has one more input
``z`` (n_batch, Q, n_joint), the play states before ``u`` (zeros at rest), and output
``z_out``, the states after it; the play operators are in the graph.  With delayed commands
(``exsur_lags``) ``z`` also holds their delay line, L = ``max(lags) + 1`` rows of scaled
commands after the Q play rows (at rest: the scaled rest command on every row).  With joints
on a static map in parallel (``exsur_own``, :mod:`~excavator_surrogate.surrogate.own_angles`)
``z`` has two rows more, last: the network's own angle θ_own [rad] and velocity ω_own [rad/s]
of every joint, which the network reads on those joints in place of ``theta`` and ``w``;
on them ``omega`` is the map's speed s(u[k - d]) and ``z_out`` carries θ_own, ω_own moved by
the network's speed (at rest: θ_own = θ0, ω_own = 0; after a measured sample: the measured
angle and velocity).  A surrogate with a velocity feature (``TrainConfig.velocity_input``)
has one more input after those, ``w`` (n_batch, n_joint) [rad/s]: the ``omega`` of the
previous step (zeros at rest), or the measured ``wrap(θ[k] - θ[k-1]) / T_s`` when synced to
a machine.

With ``uncertainty=True`` (``exsur export --uncertainty``; a merged seed ensemble, stateful
export) the graph has one more output, last: ``omega_members`` (M, n_batch, n_joint) float32,
each member's ω̂[k+1] (rad/s) from the same network call, before the speed bound and the end
stops (their mean is ``omega`` only where neither acted; their std over M, ddof 1, is the
velocity spread; on a joint on a map in parallel, member m's is the map's speed times
``1 + own_gain_dev[m]``, :func:`~excavator_surrogate.surrogate.parallel.own_gain_dev`).
Member m's angle is ``theta_next + dev_m``, its deviation ``dev_m`` (n_batch, n_joint) [rad]
a state the runtime keeps, zero at a reset, moved after every step as the environments move
it (:meth:`.uncertainty.StepUncertainty.advance`; θ' = ``theta_next``, ω = ``omega``, both
after the speed bound and the stops)::

    dev_m <- dev_m + T_s (omega_members[m] - ω)
    dev_m <- clip(θ' + dev_m, min(lo, θ'), max(hi, θ')) - θ'      (only with exsur_end_stops = 1)

with ``lo``, ``hi`` each joint's ``theta_min``, ``theta_max`` in ``exsur_spec`` (-inf, +inf
on a periodic joint or an open limit); the raw angle spread is the members' std of ``dev_m``
(ddof 1).  Without the clip a joint resting on its stop gets a spread that grows without
bound (3.6 rad after 200 steps where the env reports 0).  The band calibration and the
training coverage record travel as JSON metadata ``exsur_uncertainty`` and
``exsur_coverage`` (the checkpoint's ``metrics`` records, ``{}`` if it has none).  When the
checkpoint has a coverage record, the out-of-distribution flag is in the graph too: output
``ood`` (n_batch, n_joint) bool, after ``omega_members``, the whole test of
:func:`~excavator_surrogate.surrogate.coverage.ood_flags` (command, angle and velocity boxes,
the (angle, command) occupancy grid) on the sample the step predicts from: ``theta``, ``u``
and ω[k], which is the input ``w`` with a velocity feature, else one more input, last,
``omega_prev`` (n_batch, n_joint) [rad/s]: the previous step's ``omega`` (zeros at rest), or,
as ``w``, the measured ``wrap(θ[k] - θ[k-1]) / T_s`` after a recorded history or a measured
sample (the engine's flags, :meth:`~.engine.SurrogateEngine.observe`).

Windowed export (``mode="windowed"``, any cell including ARX): inputs ``theta`` and ``u``
of shape (n_batch, W, n_joint) and (n_batch, W, n_u) hold the last ``W`` samples (and ``z``,
(n_batch, W, Q + L [+ 2], n_joint), the command states after each of them, with play
features, delayed commands or joints on a map in parallel; ``w``, (n_batch, W, n_joint),
their velocity features, with a velocity feature); outputs ``omega`` and ``theta_next`` as
above (the encoding and normalisation are in the graph).  With joints on a map in parallel
the caller keeps each sample's ``z`` with the own rows as they were when that sample was
stepped, and the graph has one more output, ``z_out`` (n_batch, Q + L + 2, n_joint): the
last sample's ``z`` with the own rows moved (the next step's ``z`` before its command).

The batch axis is dynamic.  Metadata (``metadata_props``): ``exsur_spec`` (JSON machine
spec), ``exsur_mode``, ``exsur_window``, ``exsur_dt``, ``exsur_n_layer``, ``exsur_hidden``,
``exsur_play`` (JSON list of play half-widths, empty without play features),
``exsur_lags`` (JSON list of per-joint command delays [samples], empty without delayed commands),
``exsur_own`` (JSON list of per-joint booleans, the joints on a static map in parallel, empty
without; with them ``z`` has the two own rows),
``exsur_omega_in`` (``1`` with a velocity feature), ``exsur_end_stops`` (``1``: the graph
stops θ at the end stops of ``exsur_spec`` and bounds ω at its ``omega_max``; ``0``: it
integrates freely), ``exsur_members`` (M with the
``omega_members`` output, else ``0``), ``exsur_ood`` (``1`` with the ``ood`` output),
``exsur_units`` (JSON, per joint: ``theta``/``omega`` in rad or, for a linear joint, m, and
the ``display`` unit its mapping gave with the ``factor`` into it, :func:`units_metadata`),
``exsur_card`` (JSON: the checkpoint's description, :func:`~excavator_surrogate.evaluate.card.
describe_surrogate`: its training and validation scores, which ``exsur info model.onnx``
prints).
:class:`~.onnx_stepper.OnnxStepper` runs the exported file with the same warm-up convention as the
environments (``W - 1`` at-rest samples) and matches torch within 1e-5.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import logging
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal

import torch
from torch import nn

from ..errors import ConfigError, error_summary
from ..evaluate.card import describe_surrogate, full_json
from ..io_utils import atomic_path
from ..spec import MachineSpec
from ..surrogate.coverage import channel_names
from ..surrogate.model import Surrogate
from ..surrogate.uncertainty import stored_coverage
from .engine import Mode
from .export_graphs import (
    StatefulOod,
    StatefulVelocityOnly,
    WindowStep,
    WindowVelocityOnly,
    module_members,
)
from .fused import FusedMembersStep, FusedStep
from .surrogate_env import load_surrogate
from .uncertainty import OodFlags

OPSET = 18
Exporter = Literal["auto", "dynamo", "torchscript"]
TORCHSCRIPT_OPSETS = (11, 23)
"""The opsets the torchscript exporter wrote loadable graphs of for every graph kind tried
(torch 2.13, onnxruntime 1.32; above 23 torch refuses; below 11 it depends on the graph: it
fails on end stops' ``where`` at 7 and 8, and some graphs of 9 and 10 onnxruntime refuses).
The dynamo exporter builds opset 18 and converts down: a stateful graph of 15 to 17 is one
onnxruntime refuses (InvalidGraph), below that the converter fails (and writes 18)."""
ORT_MIN_OPSET = 7
"""The first opset onnxruntime runs (every release runs opset 7 and up: its versioning
document); an export is loaded by onnxruntime before it is kept."""
EXTRA = "pip install 'excavator-surrogate[export]'"
"""What installs the packages an export needs (onnx, onnxruntime, onnxscript)."""
QUIET_LOGGERS = ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript", "onnx_ir")
"""Loggers muted to errors during a dynamo export: their warnings (an opset the version
converter cannot reach, with its traceback) are exsur's one-line error instead."""


def export_onnx(
    ckpt: str | Path | Surrogate,
    out: str | Path,
    *,
    mode: Mode | None = None,
    opset: int = OPSET,
    exporter: Exporter = "auto",
    uncertainty: bool = False,
    verify: Callable[[Path], object] | None = None,
) -> Path:
    """Export a checkpoint to ONNX (atomically).

    The graph is written to a temporary file next to ``out`` and renamed onto it only once
    it has the opset asked for, onnxruntime loads it and ``verify`` (if given) returned: a
    failed export leaves nothing at ``out`` (an existing file there is left untouched).

    Args:
        ckpt: checkpoint path or loaded surrogate.
        out: target ``.onnx`` file.
        mode: ``stateful`` (single step with explicit ``h``/``c``; LSTM/GRU only) or
            ``windowed``; default: the checkpoint's training mode.
        opset: ONNX opset version.
        exporter: ``dynamo`` (``torch.export``-based, the supported exporter, ~3 s),
            ``torchscript`` (legacy, deprecated by torch but ~0.1 s) or ``auto`` (dynamo,
            falling back to torchscript if it fails).
        uncertainty: add the ``omega_members`` output (a merged seed ensemble, stateful
            export) and, with a coverage record in the checkpoint, the ``ood`` output (see the
            module docstring).
        verify: called with the temporary file (complete, with its metadata, loadable by
            onnxruntime) before it is renamed onto ``out``; an exception from it leaves
            ``out`` untouched (``exsur export`` steps it against torch here).

    Returns:
        The written path.

    Raises:
        ConfigError: the export extra is not installed (onnx, onnxruntime; onnxscript for
            ``exporter="dynamo"``); ``uncertainty`` for a single network or a windowed export;
            an opset the exporter cannot write for this graph (below 7 or past the installed
            onnx's last: before anything is traced), or a graph onnxruntime cannot load (the
            message says which exporter and opset to use instead).
    """
    _require_extra(exporter)
    _check_opset(opset, exporter, Path(out))
    sur = load_surrogate(ckpt, device="cpu")
    sur.to("cpu", torch.float32).eval()
    mode = mode or sur.mode
    spec = sur.spec
    n_joint, n_u = spec.n_joint, spec.n_u
    n_play = sur.norm.n_state  # rows of z (play operators, delay line, own angle and velocity)
    omega_in = sur.norm.omega_in
    n_b = 2
    if uncertainty and mode != "stateful":
        raise ConfigError(
            "export --uncertainty needs the stateful graph (--mode stateful): the member "
            "outputs come from the folded step"
        )
    if mode == "stateful":
        module: nn.Module = (FusedMembersStep(sur) if uncertainty else FusedStep(sur)).eval()
        cfg = sur.model_cfg
        args: tuple[torch.Tensor, ...] = (
            torch.zeros(n_b, n_joint),
            torch.zeros(n_b, n_u),
            torch.zeros(cfg.n_layer, n_b, cfg.hidden),
            torch.zeros(cfg.n_layer, n_b, cfg.hidden),
        )
        inputs = ["theta", "u", "h", "c"]
        outputs = ["omega", "theta_next", "h_out", "c_out"]
        axes = {"theta": {0: "batch"}, "u": {0: "batch"}, "h": {1: "batch"}, "c": {1: "batch"}}
        axes.update({"omega": {0: "batch"}, "theta_next": {0: "batch"}})
        axes.update({"h_out": {1: "batch"}, "c_out": {1: "batch"}})
        if n_play:
            args = (*args, torch.zeros(n_b, n_play, n_joint))
            inputs.append("z")
            outputs.append("z_out")
            axes.update({"z": {0: "batch"}, "z_out": {0: "batch"}})
        if omega_in:
            args = (*args, torch.zeros(n_b, n_joint))
            inputs.append("w")
            axes["w"] = {0: "batch"}
            if not n_play:
                module = StatefulVelocityOnly(module).eval()
        if uncertainty:
            outputs.append("omega_members")
            axes["omega_members"] = {1: "batch"}
            rec = stored_coverage(sur)
            if rec is not None and rec.channels == channel_names(spec):
                box = OodFlags(rec, spec, dtype=torch.float32)
                inner = getattr(module, "step", module)
                module = StatefulOod(inner, box, play=bool(n_play), omega_in=omega_in).eval()
                if not omega_in:
                    args = (*args, torch.zeros(n_b, n_joint))
                    inputs.append("omega_prev")
                    axes["omega_prev"] = {0: "batch"}
                outputs.append("ood")
                axes["ood"] = {0: "batch"}
    elif mode == "windowed":
        module = WindowStep(sur).eval()
        w = sur.window
        args = (torch.zeros(n_b, w, n_joint), torch.zeros(n_b, w, n_u))
        inputs = ["theta", "u"]
        outputs = ["omega", "theta_next"]
        axes = {"theta": {0: "batch"}, "u": {0: "batch"}}
        if n_play:
            args = (*args, torch.zeros(n_b, w, n_play, n_joint))
            inputs.append("z")
            axes["z"] = {0: "batch"}
        if sur.norm.own is not None:  # the own rows move in the graph: the next step's z
            outputs.append("z_out")
            axes["z_out"] = {0: "batch"}
        if omega_in:
            args = (*args, torch.zeros(n_b, w, n_joint))
            inputs.append("w")
            axes["w"] = {0: "batch"}
            if not n_play:
                module = WindowVelocityOnly(module).eval()
        axes.update({"omega": {0: "batch"}, "theta_next": {0: "batch"}})
    else:
        raise ConfigError(f"export mode must be 'stateful' or 'windowed', got {mode!r}")
    if exporter not in ("auto", "dynamo", "torchscript"):
        raise ConfigError(f"exporter must be 'auto', 'dynamo' or 'torchscript', got {exporter!r}")
    out = Path(out)
    with atomic_path(out) as tmp:
        used = _export(module, args, tmp, inputs, outputs, axes, opset, exporter, out)
        got = _add_metadata(
            tmp,
            sur,
            mode,
            n_member=module_members(module),
            ood=isinstance(module, StatefulOod),
            folder=None if isinstance(ckpt, Surrogate) else Path(ckpt).parent,
        )
        if got != opset:  # the exporter falls back to its own opset with only a logged warning
            raise ConfigError(
                f"{out}: the ONNX exporter cannot write opset {opset} for this graph (it wrote "
                f"opset {got}); {_opset_advice(opset, used)}"
            )
        _check_loads(tmp, out, opset, used)
        if verify is not None:
            verify(tmp)
    return out


def _require_extra(exporter: str) -> None:
    """Refuse in one line naming the extra when a package the export needs is missing: onnx
    (the metadata), onnxruntime (the load check, ``exsur export``'s verification) and, for
    the dynamo exporter, onnxscript (``auto`` falls back to torchscript without it)."""
    names = ["onnx", "onnxruntime"] + (["onnxscript"] if exporter == "dynamo" else [])
    missing = []
    for name in names:
        try:
            found = importlib.util.find_spec(name) is not None
        except (ImportError, ValueError):  # a broken install, or a blocked import
            found = False
        if not found:
            missing.append(name)
    if missing:
        raise ConfigError(
            f"exsur export needs the export extra (missing: {', '.join(missing)}): {EXTRA}"
        )


def _check_opset(opset: int, exporter: str, out: Path) -> None:
    """Refuse, before anything is traced, an opset no exporter can give a loadable graph of:
    below :data:`ORT_MIN_OPSET` (onnxruntime, which checks every export, runs none) or past
    the last opset the installed onnx defines.  An opset between them may still be refused
    after the export, by the exporter or by onnxruntime (:func:`_check_loads`)."""
    import onnx

    if isinstance(opset, bool) or not isinstance(opset, int):
        raise ConfigError(f"{out}: opset must be an integer (default {OPSET}), got {opset!r}")
    last = onnx.defs.onnx_opset_version()
    if ORT_MIN_OPSET <= opset <= last:
        return
    why = (
        f"onnxruntime runs opsets {ORT_MIN_OPSET} and up"
        if opset < ORT_MIN_OPSET
        else f"the installed onnx {onnx.__version__} defines opsets up to {last}"
    )
    used = "torchscript" if exporter == "torchscript" else "dynamo"
    raise ConfigError(
        f"{out}: the ONNX exporter cannot write opset {opset} ({why}); {_opset_advice(opset, used)}"
    )


def _opset_advice(opset: int, used: str) -> str:
    """What to do when exporter ``used`` could not write a loadable graph of ``opset``."""
    lo, hi = TORCHSCRIPT_OPSETS
    if used == "dynamo" and lo <= opset < OPSET:
        return (
            f"use --opset {OPSET} or leave the option out (default {OPSET}), or keep opset "
            f"{opset} with --exporter torchscript (it writes opsets {lo} to {hi})"
        )
    if used == "dynamo":
        return f"use --opset {OPSET} or leave the option out (default {OPSET})"
    if lo <= opset <= hi:
        return f"use --exporter dynamo, or leave --opset out (default {OPSET})"
    return f"use an opset from {lo} to {hi} or leave --opset out (default {OPSET})"


def _export(
    module: nn.Module,
    args: tuple[torch.Tensor, ...],
    tmp: Path,
    inputs: list[str],
    outputs: list[str],
    axes: dict[str, dict[int, str]],
    opset: int,
    exporter: Exporter,
    out: Path,
) -> str:
    """Write the graph to ``tmp`` with ``exporter``; return the one that wrote it
    (``dynamo`` or ``torchscript``).  ``auto`` is dynamo, falling back to torchscript if it
    fails, and torchscript for an opset below :data:`OPSET` that torchscript writes
    (:data:`TORCHSCRIPT_OPSETS`): dynamo builds opset 18 and converts it down, which fails or
    gives graphs onnxruntime refuses.  A failure is a one-line :class:`ConfigError` on ``out``."""
    if exporter == "auto" and TORCHSCRIPT_OPSETS[0] <= opset < OPSET:
        exporter = "torchscript"
    if exporter in ("auto", "dynamo"):
        try:
            _export_dynamo(module, args, tmp, inputs, outputs, axes, opset)
            return "dynamo"
        except Exception as e:
            if exporter == "dynamo":
                raise ConfigError(
                    f"{out}: the dynamo ONNX exporter failed ({error_summary(e, 160)}); "
                    "try --exporter torchscript"
                ) from e
    try:
        _export_torchscript(module, args, tmp, inputs, outputs, axes, opset)
    except Exception as e:
        raise ConfigError(
            f"{out}: the torchscript ONNX exporter cannot write opset {opset} for this graph "
            f"({error_summary(e, 160)}); {_opset_advice(opset, 'torchscript')}"
        ) from e
    return "torchscript"


def _check_loads(tmp: Path, out: Path, opset: int, used: str) -> None:
    """Refuse a graph onnxruntime cannot load (the dynamo exporter's version converter writes
    some: opset 17 of this graph is InvalidGraph); skipped without onnxruntime."""
    try:
        import onnxruntime as ort
    except ImportError:  # pragma: no cover - installed with the export extra
        return
    opts = ort.SessionOptions()
    opts.log_severity_level = 3  # errors only: the failure is the ConfigError below
    try:
        ort.InferenceSession(str(tmp), opts, providers=["CPUExecutionProvider"])
    except Exception as e:
        raise ConfigError(
            f"{out}: the {used} exporter wrote opset {opset} but onnxruntime cannot load the "
            f"graph ({type(e).__name__}); {_opset_advice(opset, used)}"
        ) from e


def _export_dynamo(
    module: nn.Module,
    args: tuple[torch.Tensor, ...],
    path: Path,
    inputs: list[str],
    outputs: list[str],
    axes: dict[str, dict[int, str]],
    opset: int,
) -> None:
    """``torch.onnx.export(dynamo=True)`` with a dynamic batch dimension (quiet: the loggers
    of :data:`QUIET_LOGGERS` show errors only, warnings are ignored)."""
    from torch.export import Dim

    batch = Dim("batch", min=1)
    shapes = tuple({ax: batch for ax in axes[name]} for name in inputs)  # positional
    loggers = [logging.getLogger(n) for n in QUIET_LOGGERS]
    levels = [lg.level for lg in loggers]
    try:
        for lg in loggers:
            lg.setLevel(logging.ERROR)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(
                module,
                args,
                str(path),
                input_names=inputs,
                output_names=outputs,
                dynamic_shapes=shapes,
                opset_version=opset,
                dynamo=True,
                verbose=False,
                external_data=False,
            )
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


def _export_torchscript(
    module: nn.Module,
    args: tuple[torch.Tensor, ...],
    path: Path,
    inputs: list[str],
    outputs: list[str],
    axes: dict[str, dict[int, str]],
    opset: int,
) -> None:
    """Legacy ``torch.onnx.export(dynamo=False)`` (deprecated in torch >= 2.9, still fast;
    quiet: warnings ignored, no graph dump on a failure)."""
    with warnings.catch_warnings(), _no_graph_dump():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            args,
            str(path),
            input_names=inputs,
            output_names=outputs,
            dynamic_axes=axes,
            opset_version=opset,
            dynamo=False,
        )


@contextlib.contextmanager
def _no_graph_dump() -> Iterator[None]:
    """Mute the torchscript exporter's C++ ONNX log while it runs: torch turns it on for good
    at the first export (``setup_onnx_logging`` tests the function ``_jit_is_onnx_log_enabled``,
    not its result) and, when the export fails (an opset it cannot write), prints the whole
    TorchScript graph on stdout.  With ``verbose=False`` that dump is all it logs."""
    c = torch._C
    dump = getattr(c, "_jit_onnx_log", None)
    if dump is None:  # pragma: no cover - other torch versions
        yield
        return
    c._jit_onnx_log = lambda *a, **k: None
    try:
        yield
    finally:
        c._jit_onnx_log = dump


def _add_metadata(
    path: Path,
    sur: Surrogate,
    mode: str,
    *,
    n_member: int = 0,
    ood: bool = False,
    folder: Path | None = None,
) -> int | None:
    """Add the exsur metadata to the ONNX file at ``path``; return its default-domain opset.
    ``folder``: the checkpoint's, whose training logs the card's ``training.pace`` reads."""
    import onnx

    model = onnx.load(str(path))
    meta = {
        "exsur_spec": json.dumps(sur.spec.to_dict()),
        "exsur_mode": mode,
        "exsur_window": str(sur.window),
        "exsur_dt": repr(float(sur.spec.dt)),
        "exsur_n_layer": str(sur.model_cfg.n_layer),
        "exsur_hidden": str(sur.model_cfg.hidden),
        "exsur_name": sur.name,
        "exsur_play": json.dumps(list(sur.norm.play_widths)),
        "exsur_lags": json.dumps(list(sur.norm.lags)),
        "exsur_own": json.dumps([] if sur.norm.own is None else list(sur.norm.own.own)),
        "exsur_omega_in": str(int(sur.norm.omega_in)),
        "exsur_end_stops": str(int(sur.limits_np() is not None)),
        "exsur_members": str(int(n_member)),
        "exsur_ood": str(int(ood)),
        "exsur_uncertainty": json.dumps((sur.metrics or {}).get("uncertainty") or {}),
        "exsur_coverage": json.dumps((sur.metrics or {}).get("coverage") or {}),
        "exsur_units": json.dumps(units_metadata(sur.spec)),
        "exsur_card": full_json(describe_surrogate(sur, folder=folder)),
    }
    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v
    _state_dims(model.graph)
    model.producer_name = "exsur"
    onnx.save(model, str(path))
    return next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), None)


def _state_dims(graph: Any) -> None:
    """Declare each state output ``X_out`` (``h_out``, ``c_out``, ``z_out``) with the fixed
    sizes of its input ``X``: the torchscript exporter leaves the state width symbolic
    (``Concath_out_dim_2``) where the dynamo exporter writes ``hidden``."""
    given = {v.name: v.type.tensor_type.shape.dim for v in graph.input}
    for out in graph.output:
        dims = given.get(out.name.removesuffix("_out")) if out.name.endswith("_out") else None
        if dims is None or len(dims) != len(out.type.tensor_type.shape.dim):
            continue
        for d_in, d_out in zip(dims, out.type.tensor_type.shape.dim):
            if d_in.HasField("dim_value") and not d_out.HasField("dim_value"):
                d_out.dim_value = d_in.dim_value  # clears the symbolic dim_param


def units_metadata(spec: MachineSpec) -> dict[str, dict[str, str]]:
    """Per joint, the units of the graph's ``theta`` / ``omega`` (stored SI: rad or m, rad/s
    or m/s) and the unit the user's mapping gave (``display``: ``rad``, ``mm`` ...; values x
    ``factor`` are in it): the ``exsur_units`` metadata."""
    return {
        j.name: {
            "theta": "m" if j.linear else "rad",
            "omega": "m/s" if j.linear else "rad/s",
            "display": j.display_unit,
            "factor": repr(j.display_factor),
        }
        for j in spec.joints
    }
