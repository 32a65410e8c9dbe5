"""DDP training: 2 CPU processes (gloo on 127.0.0.1) vs one process with the same global batch."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch

from excavator_surrogate.data import Dataset
from excavator_surrogate.errors import ConfigError
from excavator_surrogate.scale.ddp import DistContext, init_distributed, spawn_local
from excavator_surrogate.surrogate import read_checkpoint
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
from excavator_surrogate.training import TrainConfig, train

WORLD = 2
BASE: dict[str, Any] = dict(
    window=6,
    hidden=10,
    head_hidden=10,
    layers=1,
    epochs=3,
    tensorboard=False,
    seed=5,
    val_steps=80,
    lr=3e-3,
)
# per-rank batches; the single-process reference uses WORLD times as many
CFGS: dict[str, dict[str, Any]] = {
    # H = 3: several forward calls per backward; 13 windows per epoch do not fill the last batch
    "windowed": dict(BASE, horizon=3, lambda_bias=0.3, batch_size=8, epoch_samples=77),
    # free-run TBPTT chunks (many forward calls per backward), curriculum epoch 0 teacher-forced
    "stateful": dict(
        BASE,
        mode="stateful",
        seq_len=30,
        burn_in=6,
        tbptt=8,
        seq_batch=2,
        feedback="free",
        teacher_epochs=1,
        lambda_bias=0.1,
    ),
}


def _dataset() -> Dataset:
    spec = synthetic_spec(2)
    ds = Dataset(spec=spec)
    ds.episodes["train"] = [synthetic_episode(spec, n_step=150, seed=i) for i in range(3)]
    ds.episodes["val"] = [synthetic_episode(spec, n_step=100, seed=50)]
    return ds


def _single(mode: str) -> dict[str, Any]:
    kw = dict(CFGS[mode])
    key = "batch_size" if mode == "windowed" else "seq_batch"
    kw[key] = kw[key] * WORLD
    return kw


def _worker(ctx: DistContext, out: str) -> None:
    """Runs on each rank: DDP training, checking bit-identical replicas after every step."""
    torch.set_num_threads(1)
    ctx.check_every = 1
    ds = _dataset()
    root = Path(out)
    for mode, kw in CFGS.items():
        train(TrainConfig(**kw), ds, out=root / f"ddp_{mode}", show_progress=False, dist=ctx)
    # resume: 2 epochs, then continue to 3 from last.pt on every rank
    kw = CFGS["windowed"]
    train(
        TrainConfig(**{**kw, "epochs": 2}), ds, out=root / "resume", show_progress=False, dist=ctx
    )
    train(
        TrainConfig(**kw),
        ds,
        out=root / "resume",
        resume=root / "resume" / "last.pt",
        show_progress=False,
        dist=ctx,
    )
    ctx.barrier()
    if ctx.rank == 1:  # only rank 0 writes
        (root / "rank1_done").write_text(str(ctx.n_steps))


def _weights(path: Path) -> torch.Tensor:
    sd = read_checkpoint(path)["state_dict"]
    return torch.cat([v.reshape(-1) for v in sd.values()])


def test_ddp_two_processes_match_single_process(tmp_path: Path) -> None:
    spawn_local(_worker, nprocs=WORLD, args=(str(tmp_path),))
    assert int((tmp_path / "rank1_done").read_text()) > 10  # steps checked for identical replicas
    ds = _dataset()
    for mode in CFGS:
        ref = train(
            TrainConfig(**_single(mode)), ds, out=tmp_path / f"single_{mode}", show_progress=False
        )
        h_ref = read_checkpoint(ref.parent / "last.pt")["history"]
        h_ddp = read_checkpoint(tmp_path / f"ddp_{mode}" / "last.pt")["history"]
        assert [h["epoch"] for h in h_ddp] == [h["epoch"] for h in h_ref] == [0, 1, 2]
        for a, b in zip(h_ddp, h_ref):
            assert a["n_sample"] == b["n_sample"], mode
            assert a["train_loss"] == pytest.approx(b["train_loss"], rel=1e-4), mode
            assert a["val_error"] == pytest.approx(b["val_error"], rel=1e-3), mode
        w_ddp = _weights(tmp_path / f"ddp_{mode}" / "last.pt")
        w_ref = _weights(ref.parent / "last.pt")
        assert torch.allclose(w_ddp, w_ref, rtol=1e-4, atol=1e-5), (
            mode,
            float((w_ddp - w_ref).abs().max()),
        )
        assert (tmp_path / f"ddp_{mode}" / "best.pt").is_file()
        _check_record(
            tmp_path / f"ddp_{mode}", TrainConfig(**CFGS[mode]), TrainConfig(**_single(mode))
        )
    # resumed DDP run == uninterrupted DDP run
    h_res = read_checkpoint(tmp_path / "resume" / "last.pt")["history"]
    assert [h["epoch"] for h in h_res] == [0, 1, 2]
    w_res = _weights(tmp_path / "resume" / "last.pt")
    assert torch.allclose(w_res, _weights(tmp_path / "ddp_windowed" / "last.pt"), atol=1e-6)
    assert all(math.isfinite(h["train_loss"]) for h in h_res)


def _check_record(out: Path, cfg: TrainConfig, single: TrainConfig) -> None:
    """A DDP run records its processes and global batch (``config.toml`` ``[parallel]``,
    ``best.pt``'s training record): its ``config.toml`` alone, per-process batch and all, did
    not say how to train the model again.  One process with the same per-process batch is
    refused; with the global batch (``single``) it trains the model (checked above)."""
    from excavator_surrogate.stages import load_preset
    from excavator_surrogate.training.records import check_parallel_replay

    batch = "batch_size" if cfg.mode == "windowed" else "seq_batch"
    rec = {
        "world_size": WORLD,
        "batch": batch,
        "per_rank": getattr(cfg, batch),
        "global_batch": getattr(single, batch),
    }
    record = load_preset(out / "config.toml")
    assert record["parallel"] == rec
    assert read_checkpoint(out / "best.pt")["metrics"]["training"]["parallel"] == rec
    with pytest.raises(ConfigError, match=f"launch it on {WORLD} processes"):
        check_parallel_replay(record, cfg, world_size=1, where="config.toml")
    check_parallel_replay(record, single, world_size=1, where="config.toml")
    check_parallel_replay(record, cfg, world_size=WORLD, where="config.toml")


def test_shard_batch_weights_sum_to_world() -> None:
    import numpy as np

    batch = np.arange(5)
    ctxs = [DistContext(r, 3, r, "gloo", torch.device("cpu")) for r in range(3)]
    parts = [c.shard_batch(batch) for c in ctxs]
    assert sorted(np.concatenate([p[0] for p in parts]).tolist()) == [0, 1, 2, 3, 4]
    # per-rank weights n_local * N / n_global average to 1 (the DDP gradient is the global mean)
    assert sum(p[1] for p in parts) == pytest.approx(3.0)
    loc, w, n = ctxs[2].shard_batch(np.arange(2))  # rank without a share: dummy, weight 0
    assert (len(loc), w, n) == (1, 0.0, 0)


def test_ddp_flag_without_torchrun_is_a_config_error(monkeypatch: pytest.MonkeyPatch) -> None:
    for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(k, raising=False)
    assert init_distributed(device="cpu") is None
    with pytest.raises(ConfigError, match="torchrun"):
        init_distributed(device="cpu", require=True)


def _gpu_worker(ctx: DistContext, out: str) -> None:
    ctx.check_every = 1
    train(TrainConfig(**CFGS["stateful"]), _dataset(), out=Path(out), dist=ctx)


@pytest.mark.skipif(
    torch.cuda.device_count() < 2, reason="needs 2 CUDA GPUs for a 2-rank nccl run on this machine"
)
def test_ddp_nccl_two_gpus(tmp_path: Path) -> None:
    spawn_local(_gpu_worker, nprocs=2, args=(str(tmp_path),), backend="nccl", device="cuda")
    assert len(read_checkpoint(tmp_path / "last.pt")["history"]) == 3
