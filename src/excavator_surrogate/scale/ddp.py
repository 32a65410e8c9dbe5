"""Data-parallel training with ``torch.distributed`` + DistributedDataParallel (DDP).

Launch (one line, any number of processes / nodes)::

    torchrun --standalone --nproc_per_node=2 -m excavator_surrogate.cli train DATA --out DIR

``exsur train`` sees torchrun's ``WORLD_SIZE`` / ``RANK`` / ``LOCAL_RANK`` / ``MASTER_ADDR`` /
``MASTER_PORT`` variables (or ``--ddp``) and calls :func:`init_distributed`, which joins the
process group (``gloo`` on CPU, ``nccl`` on CUDA) and returns a :class:`DistContext` that
:func:`~excavator_surrogate.training.train` uses (it implements the
:class:`~excavator_surrogate.training.parallel.Parallel` interface):

- **Sharding.** Every rank draws the same per-epoch permutation of the training windows
  (windowed mode) or sub-sequences (stateful mode) from the shared seed ``(seed, epoch)``.
  Global batch ``b`` is ``perm[b*B*N : (b+1)*B*N]`` (``B`` = per-rank ``batch_size`` /
  ``seq_batch``, ``N`` = world size) and rank ``r`` takes the strided shard ``[r::N]``.  Each
  rank holds the (small) normalised training arrays in memory but only ever touches its shard.
- **Gradients.** The network is wrapped in DDP (gradients all-reduced, averaged over ranks
  during ``backward``).  Each rank's loss is scaled by ``n_local * N / n_global`` so the
  averaged gradient is exactly the gradient of the global-batch mean, also for a short last
  batch: a DDP run with per-rank batch ``B`` follows a single-process run with batch ``B*N``
  (same windows, same order) up to floating-point summation order.
- **Control.** Non-finite steps are skipped on every rank together: the one NaN rule of
  :func:`~excavator_surrogate.training.parallel.clip_and_step` (any rank's loss, or the
  all-reduced gradient norm, not finite; one small all-reduce per step for the loss flag).
  With a wall-time budget the stop flag comes from rank 0 each step, so ranks never diverge;
  the cosine learning rate depends on the planned epochs only, never on the clock, so every
  rank computes the same one without communication.
- **Rank 0 only:** validation free-run, checkpoints, ``log.csv``, TensorBoard, progress
  lines.  The validation result is broadcast, so every rank runs the same ReduceLROnPlateau /
  early-stopping / best-epoch bookkeeping.  ``--resume`` loads the same checkpoint on every
  rank (the file must be readable from every node).

The run's results do not depend on the world size beyond summation order, so a checkpoint
trained with DDP is an ordinary checkpoint (no ``module.`` prefixes).
"""

from __future__ import annotations

import contextlib
import datetime
import inspect
import logging
import math
import os
import socket
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
import torch.distributed as tdist
from torch import nn
from torch.nn.parallel import DistributedDataParallel

from ..devices import resolve_device
from ..errors import ConfigError
from ..training.parallel import clip_and_step

_log = logging.getLogger(__name__)

_ENV = ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT")


def env_world_size() -> int:
    """The number of processes torchrun-style variables describe (``WORLD_SIZE``; 1 without
    them or with a value that is not a positive integer)."""
    try:
        return max(1, int(os.environ.get("WORLD_SIZE", "1")))
    except ValueError:
        return 1


def distributed_env() -> bool:
    """True if torchrun-style variables describe a job with more than one process."""
    return env_world_size() > 1


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago on ``host`` (for local test/bench launches)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class _Dispatch(nn.Module):
    """One ``forward`` entry for DDP that dispatches to the net's methods by name."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, method: str, *args: Any) -> Any:
        if method == "forward":
            return self.net(*args)
        return getattr(self.net, method)(*args)


class DDPNet:
    """A :class:`~excavator_surrogate.surrogate.model.SurrogateNet` seen through DDP.

    ``net(x)``, ``net.forward_seq(x, state)`` and ``net.step(x_t, state)`` run through the DDP
    wrapper (so ``backward`` all-reduces the gradients); ``init_state`` and ``parameters`` are
    the wrapped module's.  Several forward calls before one ``backward`` (H-step rollouts,
    free-run TBPTT chunks) are fine: every parameter gets its gradient once per backward.
    """

    def __init__(self, net: nn.Module, ctx: DistContext) -> None:
        self.module = net
        dev = ctx.device
        kw: dict[str, Any] = {}
        params = inspect.signature(DistributedDataParallel.__init__).parameters
        # the surrogate nets have no buffers: never broadcast them in forward
        if "forward_sync_buffers" in params:
            kw["forward_sync_buffers"] = False
        else:  # pragma: no cover - torch < 2.13
            kw["broadcast_buffers"] = False
        self.ddp = DistributedDataParallel(
            _Dispatch(net),
            device_ids=[dev.index] if dev.type == "cuda" else None,
            **kw,
        )

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Windowed forward ``(n_batch, W, n_feature) -> (n_batch, n_joint)``."""
        return self.ddp("forward", x)

    def forward_seq(self, x: torch.Tensor, state: Any = None) -> Any:
        """Sequence forward, see ``SurrogateNet.forward_seq``."""
        return self.ddp("forward_seq", x, state)

    def step(self, x_t: torch.Tensor, state: Any) -> Any:
        """One-sample forward, see ``SurrogateNet.step``."""
        return self.ddp("step", x_t, state)

    def init_state(self, n_batch: int) -> Any:
        """Zero recurrent state of the wrapped net."""
        return self.module.init_state(n_batch)  # type: ignore[operator]

    def parameters(self) -> Iterator[nn.Parameter]:
        """The wrapped net's parameters (the very tensors the optimiser updates)."""
        return self.module.parameters()


@dataclass
class DistContext:
    """This process's place in a data-parallel job, and the collectives training needs.

    Attributes are plain data; every method that communicates must be called by every rank
    in the same order (they are all used in lock-step by ``train``).
    """

    rank: int
    """Global rank 0..world_size-1."""
    world_size: int
    """Number of processes."""
    local_rank: int
    """Rank on this node (selects the GPU)."""
    backend: str
    """``gloo`` or ``nccl``."""
    device: torch.device
    """Training device of this rank."""
    check_every: int = 0
    """Debug: every this many optimiser steps, check that all ranks hold bit-identical
    parameters (raises RuntimeError otherwise; 0 = never)."""
    n_steps: int = field(default=0, init=False)
    """Optimiser steps taken (incl. skipped non-finite ones)."""

    @property
    def is_main(self) -> bool:
        """True on rank 0 (validation, checkpoints, logs)."""
        return self.rank == 0

    @property
    def comm_device(self) -> torch.device:
        """Device of small control tensors (CUDA for nccl, CPU for gloo)."""
        return self.device if self.backend == "nccl" else torch.device("cpu")

    # ---- sharding -----------------------------------------------------------------------------

    def shard_batch(self, batch: np.ndarray) -> tuple[np.ndarray, float, int]:
        """This rank's strided share of one global batch.

        Args:
            batch: (n_global,) sample indices (windows' end index or sub-sequence starts).

        Returns:
            ``(local, weight, n_real)``: local indices (never empty: a rank without a share
            gets one dummy index with weight 0), the loss scale ``n_local * N / n_global`` and
            the number of real local samples.
        """
        local = batch[self.rank :: self.world_size]
        n_real = len(local)
        if n_real == 0:
            return batch[:1], 0.0, 0
        return local, n_real * self.world_size / len(batch), n_real

    def wrap(self, net: nn.Module) -> DDPNet:
        """The DDP view of ``net`` (broadcasts rank 0's weights to every rank)."""
        return DDPNet(net, self)

    # ---- optimiser step -----------------------------------------------------------------------

    def backward_step(
        self,
        loss: torch.Tensor,
        *,
        weight: float,
        net: nn.Module | DDPNet,
        opt: torch.optim.Optimizer,
        grad_clip: float,
        lr_at: Callable[[], float | None],
    ) -> bool:
        """``backward`` (gradients all-reduced by DDP), then
        :func:`~excavator_surrogate.training.parallel.clip_and_step` (the one NaN rule).

        Every rank must call this for every step.  A step is skipped on every rank together
        when any rank's loss or the all-reduced gradient norm is not finite.

        Returns:
            True if the optimiser stepped.
        """
        (loss * weight if weight != 1.0 else loss).backward()
        lr = lr_at()  # always called: it may be a collective
        loss_finite = not self.any(not bool(torch.isfinite(loss)))
        params = list(net.parameters())
        ok = clip_and_step(params, opt, grad_clip=grad_clip, lr=lr, loss_finite=loss_finite)
        self.n_steps += 1
        if self.check_every > 0 and self.n_steps % self.check_every == 0:
            self.assert_replicas_equal(params)
        return ok

    # ---- collectives --------------------------------------------------------------------------

    def all_sum(self, *values: float) -> list[float]:
        """Sum of each value over ranks (float64)."""
        t = torch.tensor(values, dtype=torch.float64, device=self.comm_device)
        tdist.all_reduce(t, op=tdist.ReduceOp.SUM)
        return [float(v) for v in t.cpu()]

    def any(self, flag: bool) -> bool:
        """True on every rank if ``flag`` is true on any rank."""
        t = torch.tensor([1.0 if flag else 0.0], device=self.comm_device)
        tdist.all_reduce(t, op=tdist.ReduceOp.MAX)
        return bool(t.item() > 0)

    def broadcast(self, obj: Any) -> Any:
        """Rank 0's ``obj`` (picklable), on every rank."""
        box = [obj if self.is_main else None]
        tdist.broadcast_object_list(box, src=0, device=self.comm_device)
        return box[0]

    def broadcast_float(self, value: float | None) -> float | None:
        """Rank 0's float (None travels as NaN)."""
        v = math.nan if value is None else float(value)
        t = torch.tensor([v], dtype=torch.float64, device=self.comm_device)
        tdist.broadcast(t, src=0)
        out = float(t.item())
        return None if math.isnan(out) else out

    def global_loss(self, loss: float, count: int) -> tuple[float, int]:
        """Sample-weighted mean of the per-rank epoch losses, and the global sample count."""
        total, n = self.all_sum(loss * count if count else 0.0, float(count))
        return (total / n if n else math.nan), int(n)

    def barrier(self) -> None:
        """Wait for every rank."""
        if self.backend == "nccl":
            tdist.barrier(device_ids=[self.device.index])
        else:
            tdist.barrier()

    def assert_replicas_equal(self, params: list[torch.Tensor] | None = None) -> None:
        """Raise RuntimeError unless every rank holds bit-identical ``params``."""
        flat = torch.cat([p.detach().reshape(-1) for p in params or []]).to(self.comm_device)
        parts = [torch.empty_like(flat) for _ in range(self.world_size)]
        tdist.all_gather(parts, flat)
        for r, p in enumerate(parts):
            if not torch.equal(p, parts[0]):
                diff = float((p - parts[0]).abs().max())
                raise RuntimeError(
                    f"DDP replicas diverged after step {self.n_steps}: rank {r} differs from "
                    f"rank 0 by up to {diff:.3g}"
                )


def init_distributed(
    *,
    device: str | torch.device = "auto",
    backend: str | None = None,
    timeout_s: float = 1800.0,
    require: bool = False,
) -> DistContext | None:
    """Join the process group described by torchrun's environment variables.

    Args:
        device: ``cpu`` / ``cuda`` / ``auto`` (each rank uses ``cuda:$LOCAL_RANK``).
        backend: ``gloo`` or ``nccl``; default ``nccl`` on CUDA, ``gloo`` otherwise.
        timeout_s: collective timeout [s] (validation runs on rank 0 while the others wait).
        require: raise if the variables are missing (``exsur train --ddp``) instead of
            returning None.

    Returns:
        The context, or None when ``WORLD_SIZE`` is absent or 1 (plain single-process run).

    Raises:
        ConfigError: variables missing with ``require``, or an unusable device/backend.
    """
    missing = [k for k in _ENV if k not in os.environ]
    if missing:
        if require:
            raise ConfigError(
                f"--ddp needs a torchrun launch ({', '.join(missing)} not set): "
                "torchrun --standalone --nproc_per_node=2 -m excavator_surrogate.cli train DATA --out DIR"
            )
        return None
    world = int(os.environ["WORLD_SIZE"])
    rank = int(os.environ["RANK"])
    local_rank = int(os.environ.get("LOCAL_RANK", rank))
    if world <= 1 and not tdist.is_initialized():
        return None
    dev = resolve_device(device, local_rank=local_rank)
    backend = backend or ("nccl" if dev.type == "cuda" else "gloo")
    if backend == "nccl" and dev.type != "cuda":
        raise ConfigError("backend nccl needs CUDA devices; use gloo for CPU training")
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if not tdist.is_initialized():
        tdist.init_process_group(
            backend=backend,
            timeout=datetime.timedelta(seconds=timeout_s),
            **({"device_id": dev} if dev.type == "cuda" else {}),
        )
    ctx = DistContext(
        rank=tdist.get_rank(),
        world_size=tdist.get_world_size(),
        local_rank=local_rank,
        backend=tdist.get_backend(),
        device=dev,
    )
    if ctx.is_main:
        _log.info(
            f"distributed: {ctx.world_size} processes, backend {ctx.backend}, device {dev.type}"
        )
    return ctx


def shutdown(ctx: DistContext | None) -> None:
    """Leave the process group (no-op for None / when already destroyed)."""
    if ctx is not None and tdist.is_initialized():
        with contextlib.suppress(Exception):
            tdist.destroy_process_group()


def _local_entry(
    rank: int,
    fn: Callable[..., Any],
    world: int,
    port: int,
    backend: str,
    device: str,
    args: tuple[Any, ...],
) -> None:
    os.environ.update(
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        WORLD_SIZE=str(world),
        LOCAL_WORLD_SIZE=str(world),
    )
    ctx = init_distributed(device=device, backend=backend, timeout_s=300.0, require=True)
    assert ctx is not None
    try:
        fn(ctx, *args)
        # leave together: a rank that destroys its gloo group while a peer is still at work
        # can abort that peer at exit ("terminate called without an active exception")
        ctx.barrier()
    finally:
        shutdown(ctx)


def spawn_local(
    fn: Callable[..., Any],
    *,
    nprocs: int = 2,
    args: tuple[Any, ...] = (),
    backend: str = "gloo",
    device: str = "cpu",
) -> None:
    """Run ``fn(ctx, *args)`` in ``nprocs`` fresh processes joined on 127.0.0.1 (tests, benches).

    ``fn`` must be importable (module level).  ``device="cuda"`` with ``backend="nccl"`` puts
    rank ``r`` on ``cuda:r``.  The rendezvous port is picked free just before the launch; if
    another process grabs it in between, the launch is retried (twice) on a new port.  Raises if
    any process fails.
    """
    import torch.multiprocessing as mp

    for attempt in range(3):
        try:
            mp.spawn(
                _local_entry,
                args=(fn, nprocs, free_port(), backend, device, args),
                nprocs=nprocs,
                join=True,
            )
            return
        except Exception as e:  # ProcessRaisedException carries the child's traceback as text
            text = str(e)
            if attempt < 2 and ("EADDRINUSE" in text or "address already in use" in text.lower()):
                _log.warning(
                    "spawn_local: the free port was taken meanwhile; retrying on another port"
                )
                continue
            raise
