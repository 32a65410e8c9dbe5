"""Portable numerics: the same trained bits on every x86-64 CPU with AVX2, at a cost in speed.

Training is bit-identical on one computer (``tests/training/test_reproducible.py``), not
across CPUs: torch's CPU kernels pick their code by instruction set, round differently, and a
free-run training grows the difference into other networks (docs/design.md, "Across CPUs").
Six kernel families differ between CPUs, measured under an emulated AVX2-only Intel CPU,
by turning the AVX-512 code off, or on an AMD CPU:

- MKL's matrix products and vector maths (VML: ``exp``, ``sqrt``): pinned by
  ``MKL_CBWR=COMPATIBLE,STRICT`` (MKL's conditional numerical reproducibility: its SSE2 code
  path, the one branch MKL honours on every x86-64 CPU; its ``AVX2`` branch holds on Intel
  CPUs only, and an AMD CPU ran its own kernels under it: other matrix-vector products,
  ``exp`` and ``sqrt``);
- ATen's vectorised element-wise functions (``tanh``, ``exp``): pinned by
  ``ATEN_CPU_CAPABILITY=avx2``;
- NumPy's AVX-512 loops (``sin``, ``exp`` in the simulator's data: the last bit of the
  simulated angles changed): turned off by ``NPY_DISABLE_CPU_FEATURES``;
- OpenBLAS, NumPy's (and SciPy's) matrix library, which picks its kernels by CPU: AVX-512
  ones on an Intel or a Zen 4 CPU, its Haswell (AVX2) ones on a Zen 5 or an AVX2-only CPU.
  They round matrix products and solves differently (the ARX and the structured fits take
  them): pinned to the Haswell kernels by ``OPENBLAS_CORETYPE=Haswell``;
- oneDNN's LSTM, which ``nn.LSTM`` uses on the CPU: not pinnable
  (``ONEDNN_MAX_CPU_ISA=AVX2`` still gave other bits), so portable numerics turn oneDNN off
  and ``nn.LSTM`` runs torch's own kernels (MKL products, ATen functions).
- VML's ``sqrt``, which Adam's step takes of its second moment, is not correctly rounded on
  every CPU even in MKL's compatible branch (an AMD CPU and an emulated Intel one round a
  fifth of the results differently): portable numerics step Adam with torch's fused CPU kernel
  (:func:`fused_adam`), whose ``sqrt`` is the vector unit's, correctly rounded everywhere.

``EXSUR_NUMERICS=portable``, set in the shell before Python starts, asks for all six. The
package's ``__init__`` sets the variables (unless already set) before it imports NumPy or
torch, :func:`apply` turns oneDNN off where a network is trained or run, and the optimiser
asks :func:`fused_adam`. Spawned training workers inherit all of it. The price is training
speed (1.05-1.9x the time on an Intel AVX-512 computer, 1.3-1.4x on an AMD one);
``bench/portable.py`` measures it and checks the bits under an emulated AVX2 CPU. The
default, ``native``, leaves NumPy and torch as they are.

:func:`environment` names what a run's bits depend on besides its data, config and seed (the
CPU, the numerics, the libraries' versions and kernel levels); simulated datasets and
trainings record it.
"""

from __future__ import annotations

import os
import platform
import sys
from importlib import metadata
from typing import Any

from .cpus import cpus_note
from .errors import ConfigError

ENV = "EXSUR_NUMERICS"
"""Environment variable that chooses the numerics: ``native`` (default) or ``portable``."""
MODES = ("native", "portable")
"""Accepted values of :data:`ENV`."""
NUMPY_AVX512 = (
    "X86_V4 AVX512_ICL AVX512_SPR "  # recent NumPy's dispatch targets (2.4 here)
    "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL"  # older NumPy's
)
"""NumPy's AVX-512 dispatch targets (names it does not know are ignored with an ImportWarning,
which Python hides by default)."""
PINS = {
    "MKL_CBWR": "COMPATIBLE,STRICT",
    "ATEN_CPU_CAPABILITY": "avx2",
    "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512,
    "OPENBLAS_CORETYPE": "Haswell",
}
"""Environment settings of portable numerics (read by MKL, ATen, NumPy and OpenBLAS when they
load)."""
PORTABLE_CAPABILITIES = ("AVX2", "DEFAULT", "NO AVX")
"""ATen CPU capabilities whose element-wise kernels are the portable ones (or plainer)."""


def mode() -> str:
    """The numerics asked for by :data:`ENV` (``native`` when unset).

    Raises:
        ConfigError: any other value.
    """
    value = os.environ.get(ENV, "native").strip().lower() or "native"
    if value not in MODES:
        raise ConfigError(
            f"{ENV}={os.environ.get(ENV)!r}: use 'native' (the default) or 'portable' "
            "(the same trained bits on every x86-64 CPU with AVX2, slower)"
        )
    return value


def prepare_environment() -> None:
    """Set :data:`PINS` (where not already set) when portable numerics are asked for.

    Called by the package's ``__init__``, before torch is imported; a bad :data:`ENV` value is
    left for :func:`apply` to report.
    """
    if os.environ.get(ENV, "").strip().lower() == "portable":
        for key, value in PINS.items():
            os.environ.setdefault(key, value)


def apply() -> str:
    """Put torch in the numerics :func:`mode` asks for; returns the mode.

    Portable: turns oneDNN off (``nn.LSTM`` then runs torch's own kernels). Native: changes
    nothing.

    Raises:
        ConfigError: a bad :data:`ENV` value.
    """
    chosen = mode()
    if chosen == "portable":
        import torch

        torch.backends.mkldnn.enabled = False
    return chosen


def fused_adam() -> bool | None:
    """Adam's ``fused`` argument: True with portable numerics (the fused CPU kernel's
    correctly rounded ``sqrt``, not VML's), None (torch's default, the for-loop step)
    otherwise, so native training keeps its models.

    Raises:
        ConfigError: a bad :data:`ENV` value.
    """
    return True if mode() == "portable" else None


def check() -> str:
    """:func:`apply`, then check that the portable pins reached torch, NumPy and OpenBLAS;
    returns the mode.

    Raises:
        ConfigError: portable numerics asked for, but ATen, NumPy or OpenBLAS already run
            wider kernels (they were imported before the package set the pins) or a pin was
            overridden with another value.
    """
    chosen = apply()
    if chosen != "portable":
        return chosen
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    found = _pins_missed()
    if capability not in PORTABLE_CAPABILITIES:
        found.append(f"ATen runs {capability} kernels")
    _refuse(found)
    return chosen


def check_numpy() -> str:
    """:func:`check` for work that runs on NumPy alone (a simulation): the pins reached
    NumPy and OpenBLAS; torch is neither imported nor checked. Returns the mode.

    Raises:
        ConfigError: as :func:`check`, for NumPy and OpenBLAS.
    """
    chosen = mode()
    if chosen == "portable":
        _refuse(_pins_missed())
    return chosen


def _pins_missed() -> list[str]:
    """What of the portable pins did not reach this process: overridden settings, NumPy's
    AVX-512 loops, OpenBLAS's other kernels."""
    wrong = {k: os.environ.get(k) for k, v in PINS.items() if os.environ.get(k) != v}
    found = [f"found {wrong}"] if wrong else []
    if wide := numpy_avx512():
        found.append(f"NumPy runs {', '.join(wide)} loops")
    blas = blas_kernels()
    if any(b["kernels"] not in (None, PINS["OPENBLAS_CORETYPE"]) for b in blas):
        found.append(f"OpenBLAS runs {', '.join(str(b['kernels']) for b in blas)} kernels")
    return found


def _refuse(found: list[str]) -> None:
    """Raise the one-line refusal of a portable run that ``found`` says would not hold."""
    if found:
        raise ConfigError(
            f"{ENV}=portable: {'; '.join(found)}; set {ENV}=portable in the shell before Python "
            f"starts and import excavator_surrogate before NumPy and torch (its pins must "
            f"reach them before they load), and leave {', '.join(PINS)} unset (exsur sets them)"
        )


def numpy_simd() -> list[str]:
    """NumPy's SIMD dispatch targets in use in this process, in its order (empty when
    unknown)."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # NumPy 1.x keeps them elsewhere: unknown
        return []
    return [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]


def numpy_avx512() -> list[str]:
    """NumPy's AVX-512 dispatch targets in use in this process (empty when unknown: with
    NumPy 1.x the portable pin is checked by its setting alone)."""
    off = set(NUMPY_AVX512.split())
    return [f for f in numpy_simd() if f in off]


def blas_kernels() -> list[dict[str, str | None]]:
    """The BLAS libraries loaded in this process (NumPy's, and SciPy's once it is loaded), as
    ``{"library", "version", "kernels", "path"}``: ``kernels`` is the code path OpenBLAS
    picked for this CPU (``Haswell``, ``SkylakeX``, ``Cooperlake``, ...), None where the
    library does not say; ``path`` the shared library's file. Read by threadpoolctl, which
    inspects the loaded libraries and changes nothing."""
    from threadpoolctl import threadpool_info

    return [
        {
            "library": str(lib.get("internal_api")),
            "version": lib.get("version"),
            "kernels": lib.get("architecture"),
            "path": str(lib.get("filepath")),
        }
        for lib in threadpool_info()
        if lib.get("user_api") == "blas"
    ]


def numpy_blas() -> str | None:
    """NumPy's matrix library and the kernels it picked for this CPU, e.g. ``openblas
    0.3.31.188.0 (Haswell kernels)``; None where no BLAS library is found."""
    import numpy as np

    libs = blas_kernels()
    own = [b for b in libs if b["path"].startswith(os.path.dirname(np.__file__))]  # numpy.libs
    if not (own or libs):
        return None
    lib = (own or libs)[0]
    kernels = f" ({lib['kernels']} kernels)" if lib["kernels"] else ""
    return f"{lib['library']} {lib['version'] or ''}".strip() + kernels


def cpu_model(*, cpuinfo: str = "/proc/cpuinfo") -> str:
    """The CPU's model name, with its family and model numbers where Linux gives them
    (``AMD EPYC (family 26, model 2)``); the platform's processor string elsewhere.
    ``cpuinfo``: the file to read (the first processor's block)."""
    fields: dict[str, str] = {}
    try:
        with open(cpuinfo, encoding="utf-8") as f:
            for line in f:
                if not line.strip():
                    break  # the first processor's block is enough
                key, _, value = line.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    name = fields.get("model name") or platform.processor() or platform.machine() or "unknown"
    if "cpu family" in fields and "model" in fields:
        return f"{name} (family {fields['cpu family']}, model {fields['model']})"
    return name


def environment() -> dict[str, Any]:
    """What a run's bits depend on besides its data, config and seed, for its record: the
    numerics (:func:`mode`), the CPU, and the versions and kernel levels of the libraries
    that compute them. Two computers that differ here may train or simulate other bits.

    Keys: ``numerics``, ``cpu``, ``cpus`` (:func:`~.cpus.cpus_note`: the CPUs planned for
    and run on, which size the recipe's plan), ``machine``, ``python``, ``numpy``, ``numpy_simd`` (its
    dispatch targets in use), ``numpy_blas`` (:func:`numpy_blas`: its matrix library and the
    kernels it picked), ``mujoco``, ``torch`` (None where not installed) and, once
    torch is loaded, ``torch_cpu_capability`` (its element-wise kernels). Reads no clock and
    no load, so the same computer gives the same record.

    Raises:
        ConfigError: a bad :data:`ENV` value.
    """

    def version(dist: str) -> str | None:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    env: dict[str, Any] = {
        "numerics": mode(),
        "cpu": cpu_model(),
        "cpus": cpus_note(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "numpy": version("numpy"),
        "numpy_simd": numpy_simd(),
        "numpy_blas": numpy_blas(),
        "mujoco": version("mujoco"),
        "torch": version("torch"),
    }
    torch = sys.modules.get("torch")  # not imported for it: a simulation needs no torch
    if torch is not None:
        env["torch_cpu_capability"] = str(torch.backends.cpu.get_cpu_capability())
    return env
