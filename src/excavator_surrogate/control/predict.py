"""Batched predictors a sampling planner rolls its candidates through.

A predictor follows the machine (``reset`` at rest, then ``observe`` every applied command
and measured angle) and, at a control step, rolls ``n_batch`` candidate command sequences
out from the machine's current state in ONE batched call (``predict``):

- :class:`SurrogatePredictor`: the learned surrogate.  A one-env
  :class:`~excavator_surrogate.env.engine.SurrogateEngine` consumes the measured history
  (teacher forcing: each step is fed the measured angle), so its recurrent state is synced
  to the machine; ``predict`` forks that state into an ``n_batch``-env engine and steps the
  candidates together, ``n_step`` batched steps (with ``workers > 1``, split over helper
  processes, :mod:`.workers`).  For a merged seed ensemble, :meth:`~SurrogatePredictor.predict_risk`
  also returns every candidate's member spread and out-of-distribution flags from the same
  batched calls (an engine that tracks the members, :func:`.workers.rollout`), which MPPI's
  ``risk`` weight adds to the cost.
- :class:`PlantPredictor`: the oracle.  It reads the full physics state of the plant (and
  the hydraulic transform's command history) and continues it with ``mujoco.rollout`` on a
  copy of the plant, i.e. planning through the plant model itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import nullcontext
from functools import partial
from itertools import pairwise
from typing import Any, Protocol

import numpy as np
import torch

from ..devices import OneThread
from ..errors import ConfigError
from ..simulate.plant import MujocoExcavator
from ..spec import MachineSpec
from ..surrogate.coverage import CoverageRecord, ood_flags
from ..surrogate.ensemble import member_head
from ..surrogate.model import Surrogate
from ..surrogate.rollout import require_finite
from ..surrogate.uncertainty import stored_coverage
from .workers import RolloutWorker, rollout


class Predictor(Protocol):
    """What :class:`~.mppi.MPPI` needs from a model of the machine."""

    spec: MachineSpec

    def reset(self, theta0: np.ndarray) -> None:
        """The machine starts at rest at ``theta0`` (n_joint,) [rad]."""
        ...

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> None:
        """The machine is mid-motion after the recorded ``theta_hist`` (n_hist, n_joint) [rad]
        and the commands ``u_hist`` (n_hist - 1, n_u) between them."""
        ...

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """The machine applied ``u`` (n_joint,) and then measured ``theta`` (n_joint,) [rad]."""
        ...

    def predict(self, u: np.ndarray) -> np.ndarray:
        """Angles ``theta[k+1..k+n_step]`` (n_batch, n_step, n_joint) [rad] after the commands
        ``u`` (n_batch, n_step, n_joint) applied from the current sample ``k``."""
        ...


class RiskPredictor(Predictor, Protocol):
    """A :class:`Predictor` that also says how sure it is (MPPI with ``risk > 0``)."""

    head: object | None
    """The ensemble members' output layer (None: a single network, no spread: refused)."""

    def predict_risk(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(theta, theta_spread, ood)`` of the commands ``u`` (n_batch, n_step, n_joint):
        angles and the members' angle spread (n_batch, n_step, n_joint) [rad], and the
        out-of-distribution flags (n_batch, n_step) bool (any joint; None: no record)."""
        ...


class SurrogatePredictor:
    """Candidates rolled out through the surrogate from its state synced to the machine.

    Args:
        sur: the surrogate (any LSTM/GRU checkpoint; stateful or windowed).
        n_batch: candidates per call (the batch of the rollout engine).
        mode: ``stateful`` / ``windowed``; default: the checkpoint's mode.
        bias_gain: weight ``a`` of the velocity-bias estimate (offset-free MPC): after every
            measured step, ``b ← (1 - a) b + a (θ_measured - θ_predicted) / T_s`` from the
            synced engine's own one-step prediction, and ``predict`` adds ``b · T_s · (n + 1)``
            to sample ``n`` of every candidate, clipped to the surrogate's end stops; 0
            (default) switches it off.
        workers: processes the candidates are split over (1: this process only; ``k > 1``:
            this one and ``k - 1`` spawned :class:`~.workers.RolloutWorker`; ``close()``
            ends them).  Each process runs one torch thread.
        inputs: the value of each exogenous input of the surrogate (``spec.inputs``, e.g.
            ``{"throttle": 1.0}``), held on every step: a planner plans the joints' commands
            only, so a surrogate with inputs needs all of them here (as the envs' ``inputs=``,
            :mod:`~excavator_surrogate.env.inputs`).  ``observe`` and ``reset_history`` take
            commands with or without their columns.

    Raises:
        ConfigError: an exogenous input without a value, an unknown one or one out of range.
    """

    def __init__(
        self,
        sur: Surrogate,
        *,
        n_batch: int,
        mode: str | None = None,
        bias_gain: float = 0.0,
        workers: int = 1,
        inputs: Mapping[str, float] | None = None,
    ) -> None:
        from ..env.engine import SurrogateEngine
        from ..env.inputs import ActionLayout

        self.layout = ActionLayout.make(sur.spec, inputs, where="SurrogatePredictor")
        free = [c.name for c in self.layout.columns[sur.spec.n_joint :]]
        if free:
            raise ConfigError(
                f"SurrogatePredictor: the surrogate also takes the exogenous input(s) "
                f"{', '.join(free)}, which a planner does not plan: hold each at a value, "
                f"inputs={{{', '.join(repr(n) + ': ...' for n in free)}}}"
            )
        if not 0.0 <= bias_gain <= 1.0:
            raise ConfigError(f"SurrogatePredictor: bias_gain must be in [0, 1], got {bias_gain}")
        if not 1 <= workers <= n_batch:
            raise ConfigError(
                f"SurrogatePredictor: workers must be in [1, n_batch = {n_batch}], got {workers}"
            )
        self.spec = sur.spec
        self.n_batch = int(n_batch)
        # candidate rows [edges[i], edges[i + 1]) go to process i (0: this one)
        edges = np.linspace(0, self.n_batch, int(workers) + 1).round().astype(int)
        self._edges = edges.tolist()
        self._engine = partial(SurrogateEngine, sur, mode=mode)
        self.sync = self._engine(n_envs=1)
        self.sync.u_rest = self.layout.rest()  # the at-rest warm-up holds the inputs too
        self.batch = self._engine(n_envs=int(edges[1]))
        self.workers: list[RolloutWorker] = []
        try:
            for a, b in pairwise(edges[1:]):
                self.workers.append(RolloutWorker(sur, n_batch=int(b - a), mode=mode))
        except BaseException:
            self.close()
            raise
        self.bias_gain = float(bias_gain)
        self.bias = np.zeros(sur.spec.n_joint)
        """Velocity-bias estimate (n_joint,) [rad/s] (zero unless ``bias_gain > 0``)."""
        self.head = member_head(self.batch.sur)
        """The members' output layer (None: a single network, no spread)."""
        self._risk_batch: Any = None  # this process's engine that tracks the members (lazy)
        self.coverage: CoverageRecord | None = stored_coverage(sur)
        """The training data's coverage record (None: no out-of-distribution flags)."""

    def reset(self, theta0: np.ndarray) -> None:
        """At rest at ``theta0`` (n_joint,): the engine's at-rest warm-up."""
        theta0 = np.asarray(theta0, dtype=np.float64)
        require_finite(theta0, self.spec, what="theta", where="SurrogatePredictor.reset")
        self.sync.reset(theta0[None])
        self.bias[:] = 0.0

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> None:
        """Mid-motion: the synced engine warmed up on the machine's recorded ``theta_hist``
        (n_hist, n_joint) [rad] and ``u_hist`` (n_hist - 1, n_u)
        (:meth:`~excavator_surrogate.env.engine.SurrogateEngine.reset_history`)."""
        th = np.asarray(theta_hist, dtype=np.float64)
        require_finite(th, self.spec, what="theta", where="SurrogatePredictor.reset_history")
        self.sync.reset_history(th[None], self._full(u_hist)[None])
        self.bias[:] = 0.0

    def _full(self, u: Any) -> np.ndarray:
        """Commands (..., n_u) from (..., n_joint) (the held inputs filled in) or (..., n_u)."""
        u = np.asarray(u, dtype=np.float64)
        u = u if u.shape[-1:] == (self.spec.n_u,) else self.layout.full(u)
        require_finite(u, self.spec, what="u", where="SurrogatePredictor")
        return u

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """Consume the applied ``u`` from the current (measured) angle, then take the measured
        ``theta`` as the new current angle."""
        theta = np.asarray(theta, dtype=np.float64)
        require_finite(theta, self.spec, what="theta", where="SurrogatePredictor.observe")
        pred, _ = self.sync.step(self._full(u)[None])
        if self.bias_gain:
            err = (theta - pred[0].cpu().numpy()) / self.spec.dt
            self.bias += self.bias_gain * (err - self.bias)
        self.sync.observe(theta[None])

    def _check(self, u: np.ndarray) -> np.ndarray:
        """The candidates ``u`` (n_batch, n_step, n_joint) as the engine's commands (n_batch,
        n_step, n_u) float32, the held inputs filled in."""
        u = np.asarray(u, dtype=np.float32)
        if u.ndim != 3 or u.shape[0] != self.n_batch or u.shape[2] != self.spec.n_joint:
            raise ConfigError(
                f"SurrogatePredictor: u must have shape ({self.n_batch}, n_step, {self.spec.n_joint}), got {u.shape}"
            )
        require_finite(u, self.spec, what="u", where="SurrogatePredictor.predict")
        return u if not self.layout.fixed else self.layout.full(u).astype(np.float32)

    @torch.inference_mode()
    def _run(self, u: np.ndarray, members: bool) -> np.ndarray:
        """The candidates' rollouts, split over the processes (see :func:`.workers.rollout`)."""
        state = self.sync.export_row(0)
        if self.workers:  # numpy, not tensors: no shared-memory files per call
            state = {k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in state.items()}
        e = self._edges
        engine = self.batch
        if members:
            if self._risk_batch is None:
                self._risk_batch = self._engine(n_envs=e[1], uncertainty=True)
            engine = self._risk_batch
        try:
            for w, a, b in zip(self.workers, e[1:-1], e[2:]):
                w.submit(state, u[a:b], members=members)
            # one torch thread per process, this one too: they share the cores
            with OneThread() if self.workers else nullcontext():
                parts = [rollout(engine, state, u[: e[1]], members)]
            parts += [w.result() for w in self.workers]
        except BaseException:
            self.close()  # no worker is left with an unread answer; later calls run here
            raise
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=-3)

    def _debias(self, theta: np.ndarray) -> np.ndarray:
        if not self.bias_gain:
            return theta
        ramp = np.arange(1, theta.shape[1] + 1)[:, None] * self.spec.dt  # (n_step, 1) [s]
        theta = theta + ramp * self.bias
        stops = self.sync._limits
        if stops is None:
            return theta
        # still inside the end stops the rollout ran in (the bias is a velocity it did not see)
        return np.clip(theta, stops[0].numpy(), stops[1].numpy())

    def predict(self, u: np.ndarray) -> np.ndarray:
        """See :meth:`Predictor.predict`; ``u`` must have ``n_batch`` rows."""
        return self._debias(self._run(self._check(u), members=False))

    def predict_risk(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """See :meth:`RiskPredictor.predict_risk`: the angles of :meth:`predict`, the members'
        angle spread (std over the members, ddof 1, of their velocities integrated along the
        merged run, as :func:`~excavator_surrogate.surrogate.uncertainty.member_runs` with
        ``design="shared"``) and the flags of
        :func:`~excavator_surrogate.surrogate.coverage.ood_flags` on the predicted angles,
        velocities and the commands.  Needs a merged seed ensemble (:class:`ConfigError`)."""
        if self.head is None:
            raise ConfigError(
                "SurrogatePredictor: a risk weight needs the spread of a merged seed ensemble "
                "(train with members >= 2, or 'exsur merge' the members again); this surrogate "
                "has no member outputs"
            )
        u = self._check(u)
        theta, omega, spread = self._run(u, members=True)
        ood = None
        if self.coverage is not None:
            ood = ood_flags(self.coverage, self.spec, theta, omega, u).any(-1)
        return self._debias(theta), spread, ood

    def close(self) -> None:
        """End the worker processes (if any); the predictor then runs in this process only."""
        if not self.workers:
            return
        for w in self.workers:
            w.close()
        self.workers = []
        self._edges = [0, self.n_batch]
        self.batch = self._engine(n_envs=self.n_batch)


class PlantPredictor:
    """The oracle: candidates rolled out with ``mujoco.rollout`` from the plant's true state.

    Args:
        plant: the machine being controlled (its ``data`` and ``transform`` are read, never
            changed).
        n_threads: ``mujoco.rollout`` threads of the planning copy.
    """

    def __init__(self, plant: MujocoExcavator, *, n_threads: int = 1) -> None:
        from dataclasses import replace

        self.plant = plant
        self.spec = plant.spec
        self.model = MujocoExcavator(
            replace(plant.config, n_threads=int(n_threads)),
            spec=plant.spec,
            command_transform=plant.transform,
        )

    def reset(self, theta0: np.ndarray) -> None:
        """Nothing to do: the oracle reads the plant's state at every call."""
        del theta0

    def reset_history(self, theta_hist: np.ndarray, u_hist: np.ndarray) -> None:
        """Nothing to do: the oracle reads the plant's state at every call."""
        del theta_hist, u_hist

    def observe(self, u: np.ndarray, theta: np.ndarray) -> None:
        """Nothing to do: the oracle reads the plant's state at every call."""
        del u, theta

    def predict(self, u: np.ndarray) -> np.ndarray:
        """See :meth:`Predictor.predict`."""
        u = np.asarray(u, dtype=np.float64)
        n_batch = u.shape[0]
        tiled = getattr(self.plant.transform, "tiled", None)
        if tiled is None:
            raise ConfigError(
                f"PlantPredictor: the plant's command transform ({type(self.plant.transform).__name__}) "
                "has no tiled(n_batch) method to fork its state"
            )
        self.model.transform = tiled(n_batch)
        state = np.repeat(self.plant.physics_state()[None], n_batch, axis=0)
        pad = np.concatenate([u, u[:, -1:]], axis=1)  # u[:, -1] of a rollout is never applied
        return self.model.rollout_from(state, pad)["theta"][:, 1:]
