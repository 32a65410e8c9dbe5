"""Run an exported ONNX surrogate with onnxruntime: :class:`OnnxStepper`.

The graph and its metadata are written by :func:`~.export.export_onnx` (its docstring lists
every input, output and metadata key); this module reads them back and steps the graph in
closed loop with the environments' warm-up convention, so a controller can run the surrogate
without torch.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CheckpointError, ConfigError
from ..spec import MachineSpec
from ..surrogate.angles import wrap_periodic
from ..surrogate.command_state import play_np
from ..surrogate.features_np import scale_commands_np
from ..surrogate.own_angles import N_OWN_ROWS
from ..surrogate.rollout import require_finite
from .fused import rest_command


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
        own = [bool(j) for j in json.loads(meta.get("exsur_own", "[]"))]
        self.own: np.ndarray | None = np.array(own, dtype=bool) if any(own) else None
        """(n_joint,) bool: the joints on a static map in parallel (None: none)."""
        self.n_command = len(self.play) + (max(self.lags) + 1 if self.lags else 0)
        """Rows Q + L of the command state proper: play operators, then the delay line."""
        self.n_state = self.n_command + (N_OWN_ROWS if self.own is not None else 0)
        """Rows of ``z``: the Q + L command rows, then (joints on a map in parallel) the
        network's own angle [rad] and velocity [rad/s] of every joint."""
        self.omega_in = meta.get("exsur_omega_in", "0") == "1"
        """Whether the graph takes a velocity feature ``w``."""
        self.n_member = int(meta.get("exsur_members", "0"))
        """M of the ``omega_members`` output (0: none)."""
        self.omega_members: np.ndarray | None = None
        """(M, n_batch, n_joint) each member's omega of the last step [rad/s] (with M > 0;
        None before the first step after a reset)."""
        self._outputs = [o.name for o in self.session.get_outputs()]
        self._omega_prev = "omega_prev" in {i.name for i in self.session.get_inputs()}
        self.ood: np.ndarray | None = None
        """(n_batch, n_joint) bool: the last step's sample left the training coverage (graphs
        with the ``ood`` output, from the first step after a reset; None otherwise)."""
        n_joint = self.spec.n_joint
        self.w = np.zeros((0, n_joint), dtype=np.float32)
        """Velocity feature (n_batch, n_joint) of the current sample [rad/s]."""
        self._w_win = np.zeros((0, self.window, n_joint), np.float32)
        self.z = np.zeros((0, self.n_state, n_joint), dtype=np.float32)
        """Command states (n_batch, Q + L [+ 2], n_joint) after the last command (stateful)
        or the last step (windowed: the own rows moved, the command rows before the next
        command)."""
        self._z_win = np.zeros((0, self.window, self.n_state, n_joint), np.float32)
        self.theta = np.zeros((0, self.spec.n_joint), dtype=np.float32)
        self.h = self.c = np.zeros((self.n_layer, 0, self.hidden), dtype=np.float32)
        self._theta_win = np.zeros((0, self.window, n_joint), np.float32)
        self._u_win = np.zeros((0, self.window, self.spec.n_u), np.float32)

    def _columns(self, what: str) -> str:
        """``what`` and its column names, for a shape error: ``theta (swing, boom, ...)``."""
        names = self.spec.names if what.startswith("theta") else self.spec.u_names
        return f"{what} ({', '.join(names)})"

    def reset(self, theta0: np.ndarray) -> np.ndarray:
        """Start every row at rest at ``theta0`` (n_batch, n_joint) [rad] (one row: also
        (n_joint,)); returns θ (float32).  The last step's :attr:`omega_members` and
        :attr:`ood` are cleared (None).

        Raises:
            ConfigError: another shape, or a non-finite angle (one line naming the joints).
        """
        theta0 = np.asarray(theta0, dtype=np.float32)
        n_joint = self.spec.n_joint
        if theta0.ndim not in (1, 2) or theta0.shape[-1] != n_joint:
            raise ConfigError(
                f"OnnxStepper.reset: theta0 must have shape (n_batch, {n_joint}), got "
                f"{theta0.shape}: one row per batch entry of {self._columns('theta')}"
            )
        theta0 = np.atleast_2d(theta0)
        require_finite(theta0, self.spec, what="theta", where="OnnxStepper.reset")
        n = theta0.shape[0]
        self.omega_members = self.ood = None
        self.theta = theta0.copy()
        u0 = np.broadcast_to(self.u_rest, (n, self.spec.n_u)).astype(np.float32)
        z_rest = self._play_update(np.zeros((n, *self.z.shape[1:]), np.float32), u0)
        q, c = len(self.play), self.n_command
        if c > q:  # at rest: the delay line holds the rest command
            z_rest[:, q:c] = z_rest[:, c - 1 : c]
        if self.own is not None:  # the network's own angle: the reset angle, at rest
            z_rest[:, c] = theta0
            z_rest[:, c + 1] = 0.0
        self.z = z_rest
        self.w = np.zeros_like(theta0)  # at rest
        if self.mode == "stateful":
            self.h = np.zeros((self.n_layer, n, self.hidden), dtype=np.float32)
            self.c = np.zeros_like(self.h)
            for _ in range(self.window - 1):
                feed = self._stateful_feed(theta0, u0, z_rest, self.w)
                _, _, self.h, self.c, *_ = self.session.run(None, feed)
        else:
            self._theta_win = np.repeat(theta0[:, None], self.window, axis=1)
            self._u_win = np.repeat(u0[:, None], self.window, axis=1)
            self._z_win = np.repeat(z_rest[:, None], self.window, axis=1)
            self._w_win = np.zeros_like(self._theta_win)
        return self.theta

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> np.ndarray:
        """Warm every row up on recorded samples instead of at rest, as
        :meth:`~.engine.SurrogateEngine.reset_history` and ``exsur evaluate``'s free run do.

        Args:
            theta_hist: (n_batch, n_hist, n_joint) angles ``theta[0..n_hist-1]`` [rad], n_hist >= 2.
            u_hist: (n_batch, n_hist - 1, n_u) commands ``u[0..n_hist-2]`` [command units].

        The command states start at rest before ``u[0]``, the velocity feature at 0 on
        ``theta[0]``; the network reads the recorded angles on every joint.  A windowed graph
        reads the last ``W - 1`` samples, a shorter history padded with its first.

        The last step's :attr:`omega_members` and :attr:`ood` are cleared (None).

        Returns:
            θ ``theta[n_hist-1]`` (n_batch, n_joint) float32.

        Raises:
            ConfigError: another shape, or a non-finite value (one line naming the columns).
        """
        th = np.asarray(theta_hist, dtype=np.float32)
        u = np.asarray(u_hist, dtype=np.float32)
        n_joint, n_u = self.spec.n_joint, self.spec.n_u
        if th.ndim != 3 or th.shape[1] < 2 or th.shape[2] != n_joint:
            raise ConfigError(
                f"OnnxStepper.reset_history: theta_hist must have shape (n_batch, n_hist>=2, "
                f"{n_joint}), got {th.shape}: {self._columns('theta')}"
            )
        n, n_hist = th.shape[:2]
        if u.shape != (n, n_hist - 1, n_u):
            raise ConfigError(
                f"OnnxStepper.reset_history: u_hist must have shape ({n}, {n_hist - 1}, {n_u}) "
                f"(n_batch, n_hist - 1, n_u), got {u.shape}: {self._columns('u')}"
            )
        require_finite(th, self.spec, what="theta", where="OnnxStepper.reset_history")
        require_finite(u, self.spec, what="u", where="OnnxStepper.reset_history")
        # w[0] = 0 (at rest on theta[0]);  w[k] = wrap(theta[k] - theta[k-1]) / T_s
        d = wrap_periodic(th[:, 1:] - th[:, :-1], self.spec.periodic)
        w = np.concatenate([np.zeros_like(th[:, :1]), d / np.float32(self.spec.dt)], axis=1)
        w = w.astype(np.float32)
        c = self.n_command
        z = np.zeros((n, self.n_state, n_joint), np.float32)  # at rest before u[0]
        z_before, z_after = [], []  # per history sample: the states before / after its command
        for k in range(n_hist - 1):
            z = z.copy()
            if self.own is not None:  # the network reads the recorded angle on every joint
                z[:, c], z[:, c + 1] = th[:, k], w[:, k]
            z_before.append(z)
            z = self._play_update(z, u[:, k])
            z_after.append(z)
        z = z.copy()
        if self.own is not None:
            z[:, c], z[:, c + 1] = th[:, -1], w[:, -1]
        self.z, self.theta, self.w = z, th[:, -1].copy(), w[:, -1].copy()
        self.omega_members = self.ood = None
        if self.mode == "stateful":
            self.h = np.zeros((self.n_layer, n, self.hidden), dtype=np.float32)
            self.c = np.zeros_like(self.h)
            for k in range(n_hist - 1):
                feed = self._stateful_feed(th[:, k], u[:, k], z_before[k], w[:, k])
                _, _, self.h, self.c, *_ = self.session.run(None, feed)
        else:
            # the W - 1 samples before the next one, oldest first (the last slot is rewritten)
            take = np.arange(n_hist - 1)[-(self.window - 1) :] if self.window > 1 else []
            pad = max(self.window - 1 - len(take), 0)
            idx = np.concatenate([np.zeros(pad, int), np.asarray(take, int), [n_hist - 2]])
            self._theta_win = th[:, idx].copy()
            self._u_win = u[:, idx].copy()
            self._w_win = w[:, idx].copy()
            self._z_win = np.stack(z_after, axis=1)[:, idx].copy()
        return self.theta

    def _stateful_feed(
        self, theta: np.ndarray, u: np.ndarray, z: np.ndarray, w: np.ndarray
    ) -> dict[str, np.ndarray]:
        """The inputs of one stateful graph call from the current ``(h, c)``: ``z`` and the
        velocity feature ``w`` only where the graph takes them (``omega_prev``, a prior's
        input, is the previous step's omega: ``w`` again)."""
        feed = {"theta": theta, "u": u, "h": self.h, "c": self.c}
        if self.n_state:
            feed["z"] = z
        if self.omega_in:
            feed["w"] = w
        if self._omega_prev:
            feed["omega_prev"] = w
        return feed

    def _play_update(self, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Command states after commands ``u`` (n, n_u) from ``z`` (n, Q + L [+ 2], n_joint):
        the play operators, then the delay line shifted by one sample (then the network's
        own angle and velocity, passed through); float32."""
        q, c = len(self.play), self.n_command
        if not c:
            return z
        us = scale_commands_np(u, self.spec)[:, None, : self.spec.n_joint]  # one sample per row
        parts = [play_np(us, self.play, z0=z[:, :q])[:, 0]] if q else []
        if c > q:
            # line[k] = (us[k-L+1], ..., us[k])   (oldest first)
            parts.append(np.concatenate([z[:, q + 1 : c], us], axis=1))
        parts.append(z[:, c:])
        return np.concatenate(parts, axis=1).astype(np.float32)

    def step(self, u: Any) -> tuple[np.ndarray, np.ndarray]:
        """Apply commands ``u`` (n_batch, n_u) (joints', then exogenous inputs'; one row: also
        (n_u,)); returns ``(theta[k+1], omega[k+1])`` float32.

        Raises:
            ConfigError: before any reset, another shape of ``u`` (a transposed array
                included) or a non-finite command (one line naming the columns).
        """
        u = np.asarray(u, dtype=np.float32)
        n, n_u = self.theta.shape[0], self.spec.n_u
        if n == 0:
            raise ConfigError(
                "OnnxStepper.step: no batch yet; call reset(theta0) or reset_history(...) first"
            )
        if u.shape != (n, n_u) and not (n == 1 and u.shape == (n_u,)):
            raise ConfigError(
                f"OnnxStepper.step: u must have shape ({n}, {n_u}) (n_batch rows of the reset, "
                f"{self._columns('u')}), got {u.shape}"
            )
        u = u.reshape(n, n_u)
        require_finite(u, self.spec, what="u", where="OnnxStepper.step")
        if self.mode == "stateful":
            feed = self._stateful_feed(self.theta, u, self.z, self.w)
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
            outs = dict(zip(self._outputs, self.session.run(None, feed)))
            omega, theta = outs["omega"], outs["theta_next"]
            self.z = outs.get("z_out", self.z)  # joints on a map in parallel: own rows moved
            self._theta_win = np.roll(self._theta_win, -1, axis=1)
            self._u_win = np.roll(self._u_win, -1, axis=1)
            self._z_win = np.roll(self._z_win, -1, axis=1)
            self._w_win = np.roll(self._w_win, -1, axis=1)
        self.theta = theta
        self.w = omega
        return theta, omega
