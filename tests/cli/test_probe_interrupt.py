"""Issue 25 probe: Ctrl-C reaches the whole process group, so every worker of a running exsur
(simulation, ensemble members, MPPI) got SIGINT too and printed a KeyboardInterrupt traceback
under the parent's 'exsur: interrupted'.  A worker now leaves quietly (status 128 + SIGINT).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

WORKER = (
    "import os, sys, time; from excavator_surrogate.orphans import die_with_parent; "
    "die_with_parent(os.getppid()); print('ready', flush=True); time.sleep(60)"
)


def test_a_worker_leaves_quietly_on_ctrl_c() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", WORKER], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait()
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert proc.returncode == 128 + signal.SIGINT


HELD = (
    "import sys, time; from pathlib import Path; from excavator_surrogate.cli import cmd_validate,"
    " main; from excavator_surrogate.io_utils import atomic_dir, atomic_path\n"
    "def run(args):\n"
    "    out = Path(args.paths[0])\n"
    "    from excavator_surrogate.outlock import lock_out; lock_out(out)\n"
    "    with atomic_dir(out, kind='dataset') as tmp, atomic_path(tmp / 'manifest.json'):\n"
    "        print('ready', flush=True); time.sleep(60)\n"
    "    return 0\n"
    "cmd_validate.run = run\n"
    "sys.exit(main(['validate', sys.argv[1]]))\n"
)


def test_sigterm_cleans_up_as_ctrl_c_does(tmp_path) -> None:
    """``kill``, ``timeout``, ``docker stop`` and batch schedulers send SIGTERM: it left the
    command's temporary folder and files behind, as SIGKILL does.  It cleans up as Ctrl-C
    does now, and says so in one line (exit 128 + 15)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HELD, str(tmp_path / "ds")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        names = [p.name for p in tmp_path.rglob(".*")]
        assert ".ds.lock" in names and any(n.startswith(".manifest.json.") for n in names)
        os.kill(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait()
    assert err == "exsur: terminated\n" and proc.returncode == 128 + signal.SIGTERM
    assert list(tmp_path.iterdir()) == []
