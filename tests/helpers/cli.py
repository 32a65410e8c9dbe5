"""Running ``exsur`` in-process in the CLI tests."""

from __future__ import annotations

import pytest

from excavator_surrogate.cli import main


def fails(capsys: pytest.CaptureFixture[str], *argv: object) -> str:
    """Run ``exsur argv``; assert exit code 2, no traceback and ONE error line, the last on
    stderr (after any progress lines); return that line."""
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err, err
    last = err.rstrip("\n").split("\n")[-1]
    assert last.startswith("exsur: error: ") and err.count("exsur: error:") == 1, err
    return last
