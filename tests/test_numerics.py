"""Portable numerics (EXSUR_NUMERICS): the pins reach torch, a late or bad setting is refused."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from excavator_surrogate import numerics
from excavator_surrogate.errors import ConfigError

_REPO = Path(__file__).resolve().parents[1]


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter with ``env`` added (none of the pins inherited)."""
    base = {k: v for k, v in os.environ.items() if k not in (numerics.ENV, *numerics.PINS)}
    return subprocess.run(
        [sys.executable, "-c", code],
        env={**base, **env},
        capture_output=True,
        text=True,
        cwd=_REPO,
        timeout=300,
    )


def test_the_mode_is_native_unless_portable_is_asked_for(monkeypatch):
    monkeypatch.delenv(numerics.ENV, raising=False)
    assert numerics.mode() == "native"
    monkeypatch.setenv(numerics.ENV, " Portable ")
    assert numerics.mode() == "portable"
    monkeypatch.setenv(numerics.ENV, "fast")
    with pytest.raises(ConfigError, match="EXSUR_NUMERICS='fast': use 'native'"):
        numerics.mode()


def test_prepare_sets_the_pins_only_for_portable_and_never_overrides_the_user(monkeypatch):
    for key in numerics.PINS:
        # set, then removed: monkeypatch restores a variable it set (here: to absent) after the
        # test, not one it found absent, and prepare_environment sets them behind its back;
        # left set, they reach the spawned workers of later simulations in this process
        monkeypatch.setenv(key, "")
        monkeypatch.delenv(key)
    monkeypatch.setenv(numerics.ENV, "native")
    numerics.prepare_environment()
    assert not any(key in os.environ for key in numerics.PINS)
    monkeypatch.setenv(numerics.ENV, "portable")
    monkeypatch.setenv("MKL_CBWR", "AVX512")
    numerics.prepare_environment()
    assert os.environ["MKL_CBWR"] == "AVX512"  # the user's own setting stays...
    assert os.environ["ATEN_CPU_CAPABILITY"] == "avx2"
    with pytest.raises(ConfigError, match="MKL_CBWR"):  # ...and the check says it breaks the pin
        numerics.check()


_PROBE = """
import json, os
import excavator_surrogate
from excavator_surrogate import numerics
import torch
print(json.dumps({
    "mode": numerics.check(),
    "capability": torch.backends.cpu.get_cpu_capability(),
    "onednn": torch.backends.mkldnn.enabled,
    "pins": {k: os.environ.get(k) for k in numerics.PINS},
    "blas": [b["kernels"] for b in numerics.blas_kernels()],
}))
"""


def test_portable_reaches_torch_in_a_fresh_process():
    run = _python(_PROBE, EXSUR_NUMERICS="portable")
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.splitlines()[-1])
    assert got["mode"] == "portable" and got["onednn"] is False
    assert got["capability"] in numerics.PORTABLE_CAPABILITIES
    assert got["pins"] == numerics.PINS
    assert got["blas"] and set(got["blas"]) <= {None, "Haswell"}  # OpenBLAS's AVX2 kernels
    native = json.loads(_python(_PROBE).stdout.splitlines()[-1])
    assert native["mode"] == "native" and native["onednn"] is True
    assert native["pins"] == {k: None for k in numerics.PINS}


def test_portable_asked_for_after_torch_loaded_is_refused_where_it_would_not_hold():
    late = """
import os, torch
torch.tanh(torch.ones(64))  # ATen has picked its kernels
os.environ["EXSUR_NUMERICS"] = "portable"
import excavator_surrogate
from excavator_surrogate import numerics
from excavator_surrogate.errors import ConfigError
try:
    numerics.check()
    print("accepted", torch.backends.cpu.get_cpu_capability())
except ConfigError as e:
    print("refused", e)
"""
    run = _python(late)
    assert run.returncode == 0, run.stderr
    verdict, rest = run.stdout.strip().split(" ", 1)
    native = json.loads(_python(_PROBE).stdout.splitlines()[-1])["capability"]
    if native in numerics.PORTABLE_CAPABILITIES:  # an AVX2 CPU: the kernels are the portable ones
        assert verdict == "accepted"
    else:
        assert verdict == "refused" and "before Python starts" in rest


def test_a_portable_simulation_is_refused_where_numpy_loaded_first(monkeypatch, tmp_path):
    """This process imported NumPy natively: a portable simulation here runs the portable
    loops and kernels only if they are the CPU's own (an AVX2-only CPU on OpenBLAS's Haswell
    kernels); elsewhere it is refused in one line, before anything is simulated."""
    from excavator_surrogate.config import load_preset
    from excavator_surrogate.simulate.config import SimulateConfig
    from excavator_surrogate.simulate.generate import simulate_dataset

    monkeypatch.setenv(numerics.ENV, "portable")
    for key, value in numerics.PINS.items():
        monkeypatch.setenv(key, value)  # set, but after NumPy and OpenBLAS loaded
    cfg = SimulateConfig.from_preset(load_preset("tiny"), seed=0)
    wide = numerics.numpy_avx512() or [
        b
        for b in numerics.blas_kernels()
        if b["kernels"] not in (None, numerics.PINS["OPENBLAS_CORETYPE"])
    ]
    if wide:
        with pytest.raises(ConfigError, match="before Python starts"):
            simulate_dataset(cfg, out=tmp_path / "ds")
        assert not (tmp_path / "ds").exists()
    else:
        assert simulate_dataset(cfg, out=tmp_path / "ds").is_dir()
    monkeypatch.setenv(numerics.ENV, "native")
    assert numerics.check_numpy() == "native"  # native numerics check nothing


def test_a_portable_training_records_it_in_every_member(tmp_path):
    code = f"""
from excavator_surrogate.surrogate import read_checkpoint
from excavator_surrogate.training import train
from tests.helpers.training import tiny_dataset, tiny_train_config
cfg = tiny_train_config(epochs=1, members=2)
best = train(cfg, tiny_dataset(2, n_train=2, n_step=120), out={str(tmp_path / "m")!r},
             show_progress=False)
t = read_checkpoint(best)["metrics"]["training"]
print(t["numerics"], *[m["numerics"] for m in t["members"]])
"""
    run = _python(code, EXSUR_NUMERICS="portable")
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["portable"] * 3


def test_the_command_line_refuses_a_bad_setting_in_one_line():
    code = "import sys\nfrom excavator_surrogate.cli import main\nsys.exit(main(['config', 'show', 'quick']))"
    run = _python(code, EXSUR_NUMERICS="fast")
    assert run.returncode != 0
    assert run.stderr.strip().splitlines() == [
        "exsur: error: EXSUR_NUMERICS='fast': use 'native' (the default) or 'portable' (the "
        "same trained bits on every x86-64 CPU with AVX2, slower)"
    ]


def test_the_environment_names_the_computer_and_the_libraries(monkeypatch):
    import numpy as np
    import torch

    monkeypatch.delenv(numerics.ENV, raising=False)
    env = numerics.environment()
    assert env["numerics"] == "native"
    assert env["numpy"] == np.__version__
    assert env["torch"].split("+")[0] == torch.__version__.split("+")[0]
    assert env["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert env["cpu"] and env["machine"] and env["python"].count(".") == 2
    assert all(isinstance(f, str) for f in env["numpy_simd"])
    assert set(numerics.numpy_avx512()) <= set(env["numpy_simd"])
    blas = numerics.blas_kernels()
    assert blas and env["numpy_blas"].startswith(blas[0]["library"])  # NumPy's, loaded
    json.dumps(env)  # it goes into manifest.json and metrics.json as it is
    assert numerics.environment() == env  # no clock, no load: the same record every time


def test_the_cpu_model_reads_the_first_processor_or_falls_back(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text(
        "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
        "model name\t: AMD EPYC\nflags\t\t: fpu avx2\n\nprocessor\t: 1\nmodel name\t: Other\n"
    )
    assert numerics.cpu_model(cpuinfo=str(info)) == "AMD EPYC (family 26, model 2)"
    info.write_text("processor\t: 0\nmodel name\t: Some CPU\n")
    assert numerics.cpu_model(cpuinfo=str(info)) == "Some CPU"
    assert numerics.cpu_model(cpuinfo=str(tmp_path / "missing"))  # the platform's string
