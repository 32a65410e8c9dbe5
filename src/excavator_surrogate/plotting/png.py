"""Writing a figure as a PNG file that exsur recognises as its own (``--overwrite`` rules)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..io_utils import atomic_path
from ..outdir import PNG_SOFTWARE


def png_path(out: str | Path) -> Path:
    """``out`` as a path, or a one-line error when it does not end in ``.png``."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ConfigError(f"{out}: the plot is written as PNG; give a file name ending in .png")
    return out


def save_png(fig: Any, out: Path, *, dpi: int) -> Path:
    """Save the matplotlib ``fig`` to ``out`` atomically, tagged with :data:`PNG_SOFTWARE`."""
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": PNG_SOFTWARE})
    return out
