"""Portable numerics: the same trained bits on every x86-64 CPU with AVX2, at a cost in speed.

Training is bit-identical on one computer (``tests/training/test_reproducible.py``), not
across CPUs: torch's CPU kernels pick their code by instruction set, round differently, and a
free-run training grows the difference into other networks (docs/design.md, "Across CPUs").
Three kernel families differ between an AVX2 and an AVX-512 CPU, measured under an emulated
AVX2-only CPU:

- MKL's matrix products: pinned by ``MKL_CBWR=AVX2,STRICT`` (MKL's conditional numerical
  reproducibility: the AVX2 code path on every CPU that has it);
- ATen's vectorised element-wise functions (``tanh``, ``exp``): pinned by
  ``ATEN_CPU_CAPABILITY=avx2``;
- oneDNN's LSTM, which ``nn.LSTM`` uses on the CPU: not pinnable
  (``ONEDNN_MAX_CPU_ISA=AVX2`` still gave other bits), so portable numerics turn oneDNN off
  and ``nn.LSTM`` runs torch's own kernels (MKL products, ATen functions).

``EXSUR_NUMERICS=portable``, set in the shell before Python starts, asks for all three. The
package's ``__init__`` sets the two variables (unless already set) before anything imports
torch, and :func:`apply` turns oneDNN off where a network is built. Spawned training workers
inherit both. The price is training speed on an AVX-512 computer (1.3-1.9x the time there);
``bench/portable.py`` measures it and checks the bits under an emulated AVX2 CPU. The default, ``native``, leaves torch as it is.
"""

from __future__ import annotations

import os

from .errors import ConfigError

ENV = "EXSUR_NUMERICS"
"""Environment variable that chooses the numerics: ``native`` (default) or ``portable``."""
MODES = ("native", "portable")
"""Accepted values of :data:`ENV`."""
PINS = {"MKL_CBWR": "AVX2,STRICT", "ATEN_CPU_CAPABILITY": "avx2"}
"""Environment settings of portable numerics (read by MKL and ATen when torch loads)."""
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


def check() -> str:
    """:func:`apply`, then check that the portable pins reached torch; returns the mode.

    Raises:
        ConfigError: portable numerics asked for, but ATen already runs wider kernels (torch
            was imported before the package set ``ATEN_CPU_CAPABILITY``) or a pin was
            overridden with another value.
    """
    chosen = apply()
    if chosen != "portable":
        return chosen
    import torch

    capability = torch.backends.cpu.get_cpu_capability()
    wrong = {k: os.environ.get(k) for k, v in PINS.items() if os.environ.get(k) != v}
    if capability not in PORTABLE_CAPABILITIES or wrong:
        found = f"ATen runs {capability} kernels" if not wrong else f"found {wrong}"
        raise ConfigError(
            f"{ENV}=portable: {found}; set {ENV}=portable in the shell before Python "
            f"starts (it must reach torch before torch loads), and leave "
            f"{', '.join(f'{k}={v}' for k, v in PINS.items())} as they are"
        )
    return chosen
