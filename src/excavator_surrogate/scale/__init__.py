"""scale stage: data-parallel training (torchrun + DDP), device selection, Optuna sweeps.

Modules (imported on demand, so ``import excavator_surrogate.env`` stays light):

- :mod:`.devices`: :func:`~.devices.resolve_device` (``cpu`` / ``cuda[:N]`` / ``auto``).
- :mod:`.ddp`: :func:`~.ddp.init_distributed`, :class:`~.ddp.DistContext`,
  :func:`~.ddp.shutdown`, :func:`~.ddp.spawn_local` (``train(..., dist=ctx)`` uses them).
- :mod:`.sweep`: :class:`~.sweep.SweepConfig`, :func:`~.sweep.run_sweep` (``exsur sweep``);
  :mod:`.sweep_checks` checks what it can before the first trial (storage URLs, the
  study a folder holds, the base); :mod:`.sweep_report` writes its report
  (:class:`~.sweep_report.SweepResult`).

See ``docs/scale.md``.
"""
