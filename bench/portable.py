"""Portable numerics (``EXSUR_NUMERICS=portable``): the same bits on another CPU, at what cost?

Two measurements, one JSON line at the end:

- **Bits across CPUs.** A small training (the data-driven recipe with one member and a
  2 x 32 LSTM, 1 epoch on a synthetic 4-joint dataset) runs natively and under user-mode QEMU emulating an AVX2-only CPU
  (``qemu-x86_64 -cpu Haswell-v4``: no AVX-512, so torch, MKL and oneDNN take their AVX2
  paths), once with native and once with portable numerics. ``best.pt`` holds no wall-clock
  value, so its bytes compare. Skipped when ``qemu-x86_64`` is not installed (Debian:
  ``apt-get install qemu-user``); on a CPU without AVX-512 the emulated CPU is no different,
  so the comparison says nothing there either (reported). The emulated CPU is an Intel one,
  so on an AMD computer (``vendor``) it also checks the pins across vendors: MKL runs other
  kernels on AMD unless told ``COMPATIBLE``.
- **Cost.** The recipe's network (2 x 128 LSTM, stateful, one member, single-threaded) trained
  for ``--epochs`` on the same data with native and with portable numerics, alternating,
  ``--repeat`` times each, each in a fresh process; the medians of the training loops' own
  epoch times (``log.csv``: training plus validation, no start-up) and their ratio. Time it
  on a quiet machine.

Goals: ``portable_same_bits_on_emulated_avx2`` (None when skipped) and
``portable_cost_le_2x``. Usage::

    python bench/portable.py [--work DIR] [--epochs 40] [--repeat 3] [--no-qemu]
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import shutil
import site
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from excavator_surrogate import numerics
from excavator_surrogate.data import write_dataset
from excavator_surrogate.io_utils import log, setup_logging
from excavator_surrogate.surrogate.synthetic import synthetic_episode, synthetic_spec

REPO = Path(__file__).resolve().parents[1]
EMULATED_CPU = "Haswell-v4"
"""QEMU CPU model: AVX2 and FMA, no AVX-512."""


def make_data(root: Path) -> Path:
    """A small synthetic 4-joint dataset: 8 training and 2 validation step-response runs."""
    spec = synthetic_spec(4)
    train = [(synthetic_episode(spec, kind="step", n_step=400, seed=i), "train") for i in range(8)]
    val = [
        (synthetic_episode(spec, kind="step", n_step=400, seed=100 + i), "val") for i in range(2)
    ]
    write_dataset(root, [*train, *val])
    return root


def _env(mode: str) -> dict[str, str]:
    """This environment without any numerics setting, then ``EXSUR_NUMERICS=mode``."""
    env = {k: v for k, v in os.environ.items() if k not in (numerics.ENV, *numerics.PINS)}
    env[numerics.ENV] = mode
    paths = [str(REPO / "src"), *site.getsitepackages()]  # the interpreter outside its venv
    env["PYTHONPATH"] = os.pathsep.join([*paths, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def train(data: Path, out: Path, mode: str, *, hidden: int, epochs: int, qemu: bool) -> Path:
    """One member of the given size trained in a fresh process (under QEMU if asked)."""
    python = os.path.realpath(sys.executable)
    argv = [python, "-m", "excavator_surrogate.cli", "train", str(data), "--out", str(out)]
    argv += ["--members", "1", "--seed", "0", "--epochs", str(epochs), "-q"]  # the recipe's
    for knob in (
        f"train.hidden={hidden}",
        f"train.head_hidden={hidden}",
        "train.tensorboard=false",
    ):
        argv += ["--set", knob]
    if qemu:
        argv = ["qemu-x86_64", "-cpu", EMULATED_CPU, *argv]
    run = subprocess.run(argv, env=_env(mode), capture_output=True, text=True)
    if run.returncode != 0:
        tail = run.stderr.strip().splitlines()[-3:]
        raise SystemExit(f"bench/portable: training failed ({' '.join(argv[:4])}): {tail}")
    return out / "best.pt"


def cpu_vendor() -> str:
    """This CPU's vendor (``GenuineIntel``, ``AuthenticAMD``; MKL picks its kernels by it)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("vendor_id"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def epoch_seconds(out: Path) -> float:
    """Training plus validation time of every epoch, from the run's own ``log.csv`` [s]."""
    with (out / "log.csv").open() as f:
        rows = list(csv.DictReader(f))
    return float(sum(float(r["epoch_s"]) + float(r["val_s"]) for r in rows))


def bits(work: Path, data: Path) -> dict:
    """best.pt digests, native and portable, on this CPU and the emulated AVX2 CPU."""
    import torch

    if shutil.which("qemu-x86_64") is None:
        return {"skipped": "qemu-x86_64 not found (apt-get install qemu-user)"}
    here = torch.backends.cpu.get_cpu_capability()
    out: dict = {"this_cpu": here, "vendor": cpu_vendor(), "emulated_cpu": EMULATED_CPU}
    for mode in numerics.MODES:
        for where, qemu in (("here", False), ("emulated", True)):
            log(f"bench/portable: {mode} numerics, {where}")
            best = train(data, work / f"bits_{mode}_{where}", mode, hidden=32, epochs=1, qemu=qemu)
            out[f"{mode}_{where}"] = sha(best)
        out[f"{mode}_same"] = out[f"{mode}_here"] == out[f"{mode}_emulated"]
    out["meaningful"] = here not in numerics.PORTABLE_CAPABILITIES
    return out


def cost(work: Path, data: Path, *, epochs: int, repeat: int) -> dict:
    """Median epoch-loop time of the recipe's network, native against portable."""
    times: dict[str, list[float]] = {m: [] for m in numerics.MODES}
    for r in range(repeat):
        for mode in numerics.MODES:
            out = work / f"cost_{mode}_{r}"
            train(data, out, mode, hidden=128, epochs=epochs, qemu=False)
            times[mode].append(round(epoch_seconds(out), 2))
            log(f"bench/portable: {mode}, run {r}: {times[mode][-1]} s for {epochs} epochs")
    med = {m: statistics.median(t) for m, t in times.items()}
    return {
        "epochs": epochs,
        "seconds": times,
        "median_s": med,
        "ratio": round(med["portable"] / med["native"], 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=None, help="keep the runs here (default: temp)")
    ap.add_argument("--epochs", type=int, default=40, help="epochs of each cost run")
    ap.add_argument("--repeat", type=int, default=3, help="cost runs per mode")
    ap.add_argument("--no-qemu", action="store_true", help="skip the emulated-CPU comparison")
    args = ap.parse_args()
    setup_logging()
    work = args.work or Path(tempfile.mkdtemp(prefix="exsur-bench-portable-"))
    work.mkdir(parents=True, exist_ok=True)
    data = make_data(work / "data") if not (work / "data").is_dir() else work / "data"
    result: dict = {"bench": "portable", "load_avg_1min": round(os.getloadavg()[0], 2)}
    result["bits"] = {"skipped": "--no-qemu"} if args.no_qemu else bits(work, data)
    result["cost"] = cost(work, data, epochs=args.epochs, repeat=args.repeat)
    b, c = result["bits"], result["cost"]
    if "skipped" not in b:
        print(
            f"best.pt here ({b['this_cpu']}) vs emulated {EMULATED_CPU}: native "
            f"{'same' if b['native_same'] else 'different'}, portable "
            f"{'same' if b['portable_same'] else 'different'}"
        )
    print(f"training time, portable / native: {c['ratio']} ({c['median_s']} s medians)")
    same = None if "skipped" in b or not b["meaningful"] else bool(b["portable_same"])
    result["goals"] = {
        "portable_same_bits_on_emulated_avx2": same,
        "portable_cost_le_2x": bool(np.isfinite(c["ratio"]) and c["ratio"] <= 2.0),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
