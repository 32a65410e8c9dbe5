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
``z_out``, the states after it; the play operators are in the graph.  A surrogate with a
velocity feature (``TrainConfig.velocity_input``) has one more input after those, ``w``
(n_batch, n_joint) [rad/s]: the ``omega`` of the previous step (zeros at rest), or the
measured ``wrap(θ[k] - θ[k-1]) / T_s`` when synced to a machine.

With ``uncertainty=True`` (``exsur export --uncertainty``; a merged seed ensemble, stateful
export) the graph has one more output, last: ``omega_members`` (M, n_batch, n_joint) float32,
each member's ω̂[k+1] (rad/s) from the same network call (their std over M, ddof 1, is the
velocity spread; member m's angle is θ plus its integrated deviation from ``omega``, as in
the environments, :mod:`.uncertainty`).  The band calibration and the training coverage
record travel as JSON metadata ``exsur_uncertainty`` and ``exsur_coverage`` (the checkpoint's
``metrics`` records, ``{}`` if it has none).  When the checkpoint has a coverage record, the
out-of-distribution flag is in the graph too: output ``ood`` (n_batch, n_joint) bool, after
``omega_members``, the whole test of
:func:`~excavator_surrogate.surrogate.coverage.ood_flags` (command, angle and velocity boxes,
the (angle, command) occupancy grid) on the sample the step predicts from: ``theta``, ``u``
and ω[k], which is the input ``w`` with a velocity feature, else one more input, last,
``omega_prev`` (n_batch, n_joint) [rad/s]: the previous step's ``omega`` (zeros at rest).

Windowed export (``mode="windowed"``, any cell including ARX): inputs ``theta`` and ``u``
of shape (n_batch, W, n_joint) and (n_batch, W, n_u) hold the last ``W`` samples (and ``z``, (n_batch, W, Q + L,
n_joint), the command states after each of them, with play features or delayed commands; ``w``, (n_batch, W,
n_joint), their velocity features, with a velocity feature); outputs ``omega`` and
``theta_next`` as above (the encoding and normalisation are in the graph).

The batch axis is dynamic.  Metadata (``metadata_props``): ``exsur_spec`` (JSON machine
spec), ``exsur_mode``, ``exsur_window``, ``exsur_dt``, ``exsur_n_layer``, ``exsur_hidden``,
``exsur_play`` (JSON list of play half-widths, empty without play features),
``exsur_lags`` (JSON list of per-joint command delays [samples], empty without delayed commands),
``exsur_omega_in`` (``1`` with a velocity feature), ``exsur_members`` (M with the
``omega_members`` output, else ``0``), ``exsur_ood`` (``1`` with the ``ood`` output),
``exsur_units`` (JSON, per joint: ``theta``/``omega`` in rad or, for a linear joint, m, and
the ``display`` unit its mapping gave with the ``factor`` into it, :func:`units_metadata`).
:class:`OnnxStepper` runs the exported file with the same warm-up convention as the
environments (``W - 1`` at-rest samples) and matches torch within 1e-5.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from ..errors import CheckpointError, ConfigError
from ..io_utils import atomic_path
from ..spec import MachineSpec
from ..surrogate.angles import integrate
from ..surrogate.command_state import command_features, play_np
from ..surrogate.coverage import channel_names
from ..surrogate.features import scale_commands_np
from ..surrogate.model import Surrogate
from ..surrogate.uncertainty import stored_coverage
from .engine import Mode
from .fused import FusedMembersStep, FusedStep, add_end_stops, end_stops, rest_command
from .surrogate_env import load_surrogate
from .uncertainty import OodFlags

OPSET = 18
Exporter = Literal["auto", "dynamo", "torchscript"]


class WindowStep(nn.Module):
    """Windowed step with encoding and normalisation in the graph:
    ``(theta (n, W, J), u (n, W, n_u)[, z (n, W, Q, J)][, w (n, W, J)]) -> (omega (n, J),
    theta_next (n, J))`` (``u``: the joints' commands, then the exogenous inputs'; ``w``: the
    velocity features [rad/s])."""

    def __init__(self, sur: Surrogate) -> None:
        super().__init__()
        self.net = sur.net
        norm = sur.norm.to("cpu", torch.float32)
        self.periodic = tuple(norm.periodic)
        for k in ("x_mean", "x_std", "y_mean", "y_std", "u_center", "u_scale", "play", "lag_index"):
            self.register_buffer(k, getattr(norm, k).clone())
        self.n_play = norm.n_play
        self.n_state = norm.n_state
        self.omega_in = norm.omega_in
        self.dt = float(sur.spec.dt)
        add_end_stops(self, sur)

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        z: torch.Tensor | None = None,
        w: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """See the class docstring."""
        parts = []
        for j, p in enumerate(self.periodic):
            th = theta[..., j : j + 1]
            parts += [torch.sin(th), torch.cos(th)] if p else [th]
        us = (u - self.u_center) / self.u_scale
        parts.append(us)
        if self.n_state:
            if z is None:
                raise ValueError("this surrogate has command states: pass z")
            nj = len(self.periodic)
            parts.append(command_features(z, us[..., :nj], self.play, self.lag_index))
        if self.omega_in:
            if w is None:
                raise ValueError("this surrogate has a velocity feature: pass w")
            parts.append(w)
        x = torch.cat(parts, dim=-1)
        y = self.net((x - self.x_mean) / self.x_std)
        theta_next, omega = integrate(
            theta[:, -1], y * self.y_std + self.y_mean, dt=self.dt, limits=end_stops(self)
        )
        return omega, theta_next


class _StatefulOod(nn.Module):
    """A stateful members step (:class:`~.fused.FusedMembersStep`) with the ``ood`` output
    last (:class:`~.uncertainty.OodFlags` on ``theta``, ``u`` and ω[k]).  The inputs after
    ``h``, ``c`` are, in order and when present: ``z``, ``w``, ``omega_prev`` (ω[k] when
    there is no ``w``)."""

    def __init__(self, step: FusedMembersStep, box: OodFlags, *, play: bool, omega_in: bool):
        super().__init__()
        self.step, self.box = step, box
        self.play, self.omega_in = play, omega_in

    def forward(
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        e1: torch.Tensor | None = None,
        e2: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, ...]:
        """The step's outputs, then ``ood``."""
        rest = [e for e in (e1, e2) if e is not None]
        z = rest.pop(0) if self.play else None
        w = rest.pop(0) if self.omega_in else None
        omega_k = w if w is not None else rest.pop(0)
        outs = self.step(theta, u, h, c, z, w)
        return (*outs, self.box(theta, u, omega_k))


class _VelocityOnly(nn.Module):
    """``forward(theta, u, [h, c,] w)`` of a step without play features: the velocity
    feature is the graph's last input (no ``z`` input in between)."""

    def __init__(self, step: nn.Module) -> None:
        super().__init__()
        self.step = step


class _StatefulVelocityOnly(_VelocityOnly):
    def forward(  # type: ignore[override]
        self,
        theta: torch.Tensor,
        u: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        w: torch.Tensor,
    ) -> tuple[torch.Tensor, ...]:
        """:class:`~.fused.FusedStep` with ``z = None``."""
        return self.step(theta, u, h, c, None, w)


class _WindowVelocityOnly(_VelocityOnly):
    def forward(  # type: ignore[override]
        self, theta: torch.Tensor, u: torch.Tensor, w: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        """:class:`WindowStep` with ``z = None``."""
        return self.step(theta, u, None, w)


def export_onnx(
    ckpt: str | Path | Surrogate,
    out: str | Path,
    *,
    mode: Mode | None = None,
    opset: int = OPSET,
    exporter: Exporter = "auto",
    uncertainty: bool = False,
) -> Path:
    """Export a checkpoint to ONNX (atomically).

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

    Returns:
        The written path.

    Raises:
        ConfigError: ``uncertainty`` for a single network or a windowed export.
    """
    sur = load_surrogate(ckpt, device="cpu")
    sur.to("cpu", torch.float32).eval()
    mode = mode or sur.mode
    spec = sur.spec
    n_joint, n_u = spec.n_joint, spec.n_u
    n_play = sur.norm.n_state  # rows of the command state z (play operators, delay line)
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
                module = _StatefulVelocityOnly(module).eval()
        if uncertainty:
            outputs.append("omega_members")
            axes["omega_members"] = {1: "batch"}
            rec = stored_coverage(sur)
            if rec is not None and rec.channels == channel_names(spec):
                box = OodFlags(rec, spec, dtype=torch.float32)
                inner = getattr(module, "step", module)
                module = _StatefulOod(inner, box, play=bool(n_play), omega_in=omega_in).eval()
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
        if omega_in:
            args = (*args, torch.zeros(n_b, w, n_joint))
            inputs.append("w")
            axes["w"] = {0: "batch"}
            if not n_play:
                module = _WindowVelocityOnly(module).eval()
        axes.update({"omega": {0: "batch"}, "theta_next": {0: "batch"}})
    else:
        raise ConfigError(f"export mode must be 'stateful' or 'windowed', got {mode!r}")
    if exporter not in ("auto", "dynamo", "torchscript"):
        raise ConfigError(f"exporter must be 'auto', 'dynamo' or 'torchscript', got {exporter!r}")
    out = Path(out)
    with atomic_path(out) as tmp:
        if exporter in ("auto", "dynamo"):
            try:
                _export_dynamo(module, args, tmp, inputs, outputs, axes, opset)
            except Exception as e:
                if exporter == "dynamo":
                    raise ConfigError(
                        f"dynamo ONNX export failed ({type(e).__name__}: "
                        f"{str(e).splitlines()[0][:160]}); try exporter='torchscript'"
                    ) from e
                _export_torchscript(module, args, tmp, inputs, outputs, axes, opset)
        else:
            _export_torchscript(module, args, tmp, inputs, outputs, axes, opset)
        got = _add_metadata(
            tmp, sur, mode, n_member=module_members(module), ood=isinstance(module, _StatefulOod)
        )
        if got != opset:  # the exporter falls back to its own opset with only a logged warning
            raise ConfigError(
                f"{out}: the ONNX exporter cannot write opset {opset} for this graph (it wrote "
                f"opset {got}); use --opset {got} or leave the option out (default {OPSET})"
            )
    return out


def module_members(module: nn.Module) -> int:
    """M of an exported step with the ``omega_members`` output, else 0."""
    inner = getattr(module, "step", module)
    return int(inner.n_member) if isinstance(inner, FusedMembersStep) else 0


def _export_dynamo(
    module: nn.Module,
    args: tuple[torch.Tensor, ...],
    path: Path,
    inputs: list[str],
    outputs: list[str],
    axes: dict[str, dict[int, str]],
    opset: int,
) -> None:
    """``torch.onnx.export(dynamo=True)`` with a dynamic batch dimension (quiet)."""
    import logging

    from torch.export import Dim

    batch = Dim("batch", min=1)
    shapes = tuple({ax: batch for ax in axes[name]} for name in inputs)  # positional
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.export", "torch._dynamo")]
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
    """Legacy ``torch.onnx.export(dynamo=False)`` (deprecated in torch >= 2.9, still fast)."""
    with warnings.catch_warnings():
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


def _add_metadata(
    path: Path, sur: Surrogate, mode: str, *, n_member: int = 0, ood: bool = False
) -> int | None:
    """Add the exsur metadata to the ONNX file at ``path``; return its default-domain opset."""
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
        "exsur_omega_in": str(int(sur.norm.omega_in)),
        "exsur_members": str(int(n_member)),
        "exsur_ood": str(int(ood)),
        "exsur_uncertainty": json.dumps((sur.metrics or {}).get("uncertainty") or {}),
        "exsur_coverage": json.dumps((sur.metrics or {}).get("coverage") or {}),
        "exsur_units": json.dumps(units_metadata(sur.spec)),
    }
    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v
    model.producer_name = "exsur"
    onnx.save(model, str(path))
    return next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), None)


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


class OnnxStepper:
    """Closed-loop stepper over an exported ONNX surrogate (onnxruntime, CPU).

    Same convention as :class:`~.engine.SurrogateEngine`: :meth:`reset` puts every batch row at
    rest at ``theta0`` with a warm-up of ``W - 1`` at-rest samples; :meth:`step` returns
    ``(theta[k+1], omega[k+1])``.

    Args:
        path: the ``.onnx`` file written by :func:`export_onnx`.
        n_threads: onnxruntime intra-op threads.
    """

    def __init__(self, path: str | Path, *, n_threads: int = 1) -> None:
        import onnxruntime as ort

        path = Path(path)
        if not path.is_file():
            raise CheckpointError(
                f"{path}: ONNX file not found (create it with 'exsur export CKPT --out FILE')"
            )
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(n_threads)
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise CheckpointError(f"{path}: onnxruntime cannot load it ({type(e).__name__})") from e
        meta = self.session.get_modelmeta().custom_metadata_map
        if "exsur_spec" not in meta:
            raise CheckpointError(f"{path}: not an exsur export (no exsur_spec metadata)")
        self.spec = MachineSpec.from_dict(json.loads(meta["exsur_spec"]))
        self.mode = meta["exsur_mode"]
        self.window = int(meta["exsur_window"])
        self.n_layer = int(meta["exsur_n_layer"])
        self.hidden = int(meta["exsur_hidden"])
        self.u_rest = rest_command(self.spec).astype(np.float32)
        self.play = np.asarray(json.loads(meta.get("exsur_play", "[]")), dtype=np.float32)
        """(Q,) play half-widths (empty: no play features)."""
        self.lags = [int(d) for d in json.loads(meta.get("exsur_lags", "[]"))]
        """(n_joint,) command delays of the delayed-command features [samples] (empty: none)."""
        self.n_state = len(self.play) + (max(self.lags) + 1 if self.lags else 0)
        """Rows Q + L of the command state ``z``: play operators, then the delay line."""
        self.omega_in = meta.get("exsur_omega_in", "0") == "1"
        """Whether the graph takes a velocity feature ``w``."""
        self.n_member = int(meta.get("exsur_members", "0"))
        """M of the ``omega_members`` output (0: none)."""
        self.omega_members: np.ndarray | None = None
        """(M, n_batch, n_joint) each member's omega of the last step [rad/s] (with M > 0)."""
        self._outputs = [o.name for o in self.session.get_outputs()]
        self._omega_prev = "omega_prev" in {i.name for i in self.session.get_inputs()}
        self.ood: np.ndarray | None = None
        """(n_batch, n_joint) bool: the last step's sample left the training coverage (graphs
        with the ``ood`` output; None otherwise)."""
        n_joint = self.spec.n_joint
        self.w = np.zeros((0, n_joint), dtype=np.float32)
        """Velocity feature (n_batch, n_joint) of the current sample [rad/s]."""
        self._w_win = np.zeros((0, self.window, n_joint), np.float32)
        self.z = np.zeros((0, self.n_state, n_joint), dtype=np.float32)
        """Command states (n_batch, Q + L, n_joint) after the last command."""
        self._z_win = np.zeros((0, self.window, self.n_state, n_joint), np.float32)
        self.theta = np.zeros((0, self.spec.n_joint), dtype=np.float32)
        self.h = self.c = np.zeros((self.n_layer, 0, self.hidden), dtype=np.float32)
        self._theta_win = np.zeros((0, self.window, n_joint), np.float32)
        self._u_win = np.zeros((0, self.window, self.spec.n_u), np.float32)

    def reset(self, theta0: np.ndarray) -> np.ndarray:
        """Start every row at rest at ``theta0`` (n_batch, n_joint) [rad]; returns θ (float32)."""
        theta0 = np.atleast_2d(np.asarray(theta0, dtype=np.float32))
        n = theta0.shape[0]
        self.theta = theta0.copy()
        u0 = np.broadcast_to(self.u_rest, (n, self.spec.n_u)).astype(np.float32)
        z_rest = self._play_update(np.zeros((n, *self.z.shape[1:]), np.float32), u0)
        if self.n_state > len(self.play):  # at rest: the delay line holds the rest command
            z_rest[:, len(self.play) :] = z_rest[:, -1:]
        self.z = z_rest
        self.w = np.zeros_like(theta0)  # at rest
        if self.mode == "stateful":
            self.h = np.zeros((self.n_layer, n, self.hidden), dtype=np.float32)
            self.c = np.zeros_like(self.h)
            for _ in range(self.window - 1):
                feed = {"theta": theta0, "u": u0, "h": self.h, "c": self.c}
                if self.n_state:
                    feed["z"] = z_rest
                if self.omega_in:
                    feed["w"] = self.w
                if self._omega_prev:
                    feed["omega_prev"] = self.w
                _, _, self.h, self.c, *_ = self.session.run(None, feed)
        else:
            self._theta_win = np.repeat(theta0[:, None], self.window, axis=1)
            self._u_win = np.repeat(u0[:, None], self.window, axis=1)
            self._z_win = np.repeat(z_rest[:, None], self.window, axis=1)
            self._w_win = np.zeros_like(self._theta_win)
        return self.theta

    def _play_update(self, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Command states after commands ``u`` (n, n_u) from ``z`` (n, Q + L, n_joint):
        the play operators, then the delay line shifted by one sample; float32."""
        if not self.n_state:
            return z
        q = len(self.play)
        us = scale_commands_np(u, self.spec)[:, None, : self.spec.n_joint]  # one sample per row
        parts = [play_np(us, self.play, z0=z[:, :q])[:, 0]] if q else []
        if self.n_state > q:
            parts.append(np.concatenate([z[:, q + 1 :], us], axis=1))
        return np.concatenate(parts, axis=1).astype(np.float32)

    def step(self, u: Any) -> tuple[np.ndarray, np.ndarray]:
        """Apply commands ``u`` (n_batch, n_u) (joints', then exogenous inputs'); returns
        ``(theta[k+1], omega[k+1])`` float32."""
        u = np.asarray(u, dtype=np.float32).reshape(self.theta.shape[0], self.spec.n_u)
        if self.mode == "stateful":
            feed = {"theta": self.theta, "u": u, "h": self.h, "c": self.c}
            if self.omega_in:
                feed["w"] = self.w
            if self.n_state:
                feed["z"] = self.z
            if self._omega_prev:
                feed["omega_prev"] = self.w  # the previous step's omega
            outs = dict(zip(self._outputs, self.session.run(None, feed)))
            omega, theta, self.h, self.c = (
                outs[k] for k in ("omega", "theta_next", "h_out", "c_out")
            )
            self.z = outs.get("z_out", self.z)
            self.omega_members = outs.get("omega_members")
            self.ood = outs.get("ood")
        else:
            self.z = self._play_update(self.z, u)
            self._theta_win[:, -1] = self.theta
            self._u_win[:, -1] = u
            feed = {"theta": self._theta_win, "u": self._u_win}
            if self.n_state:
                self._z_win[:, -1] = self.z
                feed["z"] = self._z_win
            if self.omega_in:
                self._w_win[:, -1] = self.w
                feed["w"] = self._w_win
            omega, theta = self.session.run(None, feed)
            self._theta_win = np.roll(self._theta_win, -1, axis=1)
            self._u_win = np.roll(self._u_win, -1, axis=1)
            self._z_win = np.roll(self._z_win, -1, axis=1)
            self._w_win = np.roll(self._w_win, -1, axis=1)
        self.theta = theta
        self.w = omega
        return theta, omega
