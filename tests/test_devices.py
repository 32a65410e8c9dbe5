"""Device resolution (cpu / cuda / auto) and, on CUDA machines only, training + rollout on the GPU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from excavator_surrogate import devices
from excavator_surrogate.devices import resolve_device
from excavator_surrogate.errors import ConfigError

NO_CUDA = "needs a CUDA GPU (torch.cuda.is_available() is False on this machine)"


def test_auto_and_cpu_resolve_without_cuda(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(devices, "cuda_usable", lambda: False)
    assert resolve_device("auto") == torch.device("cpu")
    assert resolve_device(None) == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    with pytest.raises(ConfigError, match="not available"):
        resolve_device("cuda")
    with pytest.raises(ConfigError, match="unknown device"):
        resolve_device("gpu0")


def test_auto_picks_the_local_rank_gpu(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(devices, "cuda_usable", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setenv("LOCAL_RANK", "1")
    assert resolve_device("auto") == torch.device("cuda", 1)
    assert resolve_device("cuda", local_rank=0) == torch.device("cuda", 0)
    assert resolve_device("cuda:0") == torch.device("cuda", 0)
    with pytest.raises(ConfigError, match="only 2 CUDA"):
        resolve_device("cuda:3")


@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
def test_train_rollout_and_env_on_cuda(tmp_path: Path) -> None:
    from excavator_surrogate.data import Dataset
    from excavator_surrogate.env.surrogate_env import load_surrogate
    from excavator_surrogate.surrogate import load_checkpoint, rollout
    from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec
    from excavator_surrogate.training import TrainConfig, train

    spec = synthetic_spec(2)
    ds = Dataset(spec=spec)
    ds.episodes["train"] = [synthetic_episode(spec, n_step=150, seed=i) for i in range(2)]
    ds.episodes["val"] = [synthetic_episode(spec, n_step=100, seed=9)]
    runs = {
        "windowed": dict(mode="windowed"),
        "stateful": dict(mode="stateful", seq_len=30, burn_in=5, tbptt=5, seq_batch=2),
        "free": dict(
            mode="stateful", seq_len=30, burn_in=5, tbptt=5, seq_batch=2, feedback="free",
            teacher_epochs=0,
        ),
    }  # fmt: skip
    for name, kw in runs.items():  # every training path, the fused free-run cell included
        cfg = TrainConfig(
            window=5, hidden=8, head_hidden=8, epochs=2, device="auto", tensorboard=False, **kw
        )  # fmt: skip
        best = train(cfg, ds, out=tmp_path / name, show_progress=False)
        gpu = load_surrogate(best, device="auto")
        assert gpu.device.type == "cuda"
        cpu = load_checkpoint(best)
        ep = ds.val[0]
        th_g, _ = rollout(gpu, ep.theta[None], ep.u[None])
        th_c, _ = rollout(cpu, ep.theta[None], ep.u[None])
        np.testing.assert_allclose(th_g, th_c, atol=1e-4)


def test_torch_threads_sets_and_restores_the_count() -> None:
    prev = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        with devices.torch_threads(1):
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with devices.torch_threads(0):  # 0: unchanged
            assert torch.get_num_threads() == 2
        with pytest.raises(RuntimeError), devices.torch_threads(1):
            raise RuntimeError("restored on the way out too")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(prev)
