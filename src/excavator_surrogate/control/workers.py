"""Candidate rollouts in helper processes: a planner's batch split over the cores.

One surrogate step at a few hundred candidates is a chain of small matmuls that a second
torch thread barely speeds up (1.08x measured), and Python threads contend for the GIL
(0.8x).  :class:`RolloutWorker` is a spawned process with its own
:class:`~excavator_surrogate.env.engine.SurrogateEngine` for its share of the candidates;
every call sends it the synced state (:meth:`~excavator_surrogate.env.engine.SurrogateEngine.export_row`)
and its commands, it forks its engine from that state and returns the angles, while the
calling process rolls out its own share.
"""

from __future__ import annotations

import multiprocessing as mp
import weakref
from functools import partial
from typing import Any

import numpy as np
import torch

from ..env.uncertainty import member_std
from ..errors import ExsurError
from ..io_utils import worker_log_config
from ..orphans import die_with_parent, parent_args
from ..surrogate.model import Surrogate


@torch.inference_mode()
def rollout(engine: Any, state: dict[str, Any], u: np.ndarray, members: bool = False) -> np.ndarray:
    """Fork ``engine`` from ``state`` and step the commands ``u`` (n_batch, n_step, n_u).

    Returns the angles ``theta[k+1..k+n_step]`` (n_batch, n_step, n_joint) [rad], float64.
    With ``members`` (``engine`` built with ``uncertainty=True`` on a merged ensemble):
    ``(3, n_batch, n_step, n_joint)``, the angles, the velocities [rad/s] and the members'
    angle spread [rad], the std over the members of the engine's own member deviations
    (:class:`~excavator_surrogate.env.uncertainty.StepUncertainty`, design ``shared``), from
    the same calls.
    """
    engine.fork_state(state)  # also restarts the members' deviations at zero
    u_t = torch.from_numpy(np.ascontiguousarray(u, dtype=np.float32))
    n_batch, n_step, _ = u.shape
    out = torch.empty(
        3 if members else 1, n_batch, n_step, engine.spec.n_joint, dtype=torch.float64
    )
    for k in range(n_step):
        theta, omega = engine.step(u_t[:, k])
        out[0, :, k] = theta
        if members:
            dev = engine.unc.dev  # (M, n_batch, n_joint) [rad]
            out[1, :, k] = omega
            out[2, :, k] = member_std(dev) if dev.shape[0] > 1 else 0.0
    return out.numpy() if members else out[0].numpy()


def _serve(
    conn: Any,
    sur: Surrogate,
    n_batch: int,
    mode: str | None,
    log_config: tuple[int, bool],
    parent: tuple[int, bool] | None = None,
) -> None:
    """Worker process: build the engine, then answer ``(state, u)`` requests until ``None``;
    leaves within about a second of the death of ``parent`` (:func:`~excavator_surrogate.orphans.parent_args`)."""
    from ..env.engine import SurrogateEngine
    from ..io_utils import init_worker_logging

    if parent is not None:
        die_with_parent(*parent)

    init_worker_logging(log_config, tag="exsur-rollout")  # the parent's level

    torch.set_num_threads(1)
    make = partial(SurrogateEngine, sur, n_envs=n_batch, mode=mode)
    try:
        engines = {False: make()}  # with members: a second engine, built on first use
        conn.send(("ready", engines[False].impl))
    except Exception as e:  # reported to the parent, which raises it
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the parent is gone
            return
        if msg is None:
            return
        try:
            state, u, members = msg
            if members not in engines:
                engines[members] = make(uncertainty=True)
            conn.send(("ok", rollout(engines[members], state, u, members)))
        except Exception as e:
            conn.send(("error", f"{type(e).__name__}: {e}"))


_DIED = (
    "a rollout worker process died; rerun with workers=1 (one process) to see why (workers are "
    "spawned: a script that starts them needs its code under `if __name__ == '__main__':`)"
)


class RolloutWorker:
    """A spawned process stepping ``n_batch`` candidates of the surrogate ``sur``.

    ``submit(state, u)`` starts a rollout and returns at once; ``result()`` waits for its
    angles.  ``close()`` (also at garbage collection) ends the process.
    """

    def __init__(self, sur: Surrogate, *, n_batch: int, mode: str | None = None) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve,
            args=(child, sur, int(n_batch), mode, worker_log_config(), parent_args()),
            daemon=True,
            name="exsur-rollout",
        )
        self._proc.start()
        child.close()
        self._finalizer = weakref.finalize(self, _stop, self._conn, self._proc)
        self.impl = str(self._receive())
        """The worker engine's stateful kernel (``cell``, ``module``, ``members``)."""

    def _receive(self) -> Any:
        try:
            tag, value = self._conn.recv()
        except (EOFError, OSError) as e:
            raise ExsurError(_DIED) from e
        if tag == "error":
            raise ExsurError(f"rollout worker: {value}")
        return value

    def submit(self, state: dict[str, Any], u: np.ndarray, *, members: bool = False) -> None:
        """Send the synced ``state`` and the commands ``u`` (n_batch, n_step, n_u); with
        ``members``, :meth:`result` also holds velocities and spread (see :func:`rollout`)."""
        try:
            self._conn.send((state, np.ascontiguousarray(u, dtype=np.float32), bool(members)))
        except OSError as e:  # BrokenPipeError: the process is gone
            raise ExsurError(_DIED) from e

    def result(self) -> np.ndarray:
        """The angles (n_batch, n_step, n_joint) [rad] of the last :meth:`submit` (with
        ``members``: (3, n_batch, n_step, n_joint), see :func:`rollout`)."""
        return np.asarray(self._receive())

    def close(self) -> None:
        """End the worker process."""
        self._finalizer()


def _stop(conn: Any, proc: Any) -> None:
    try:
        conn.send(None)
    except (BrokenPipeError, OSError):
        pass
    proc.join(timeout=5)
    if proc.is_alive():
        proc.terminate()
        proc.join()
    conn.close()
