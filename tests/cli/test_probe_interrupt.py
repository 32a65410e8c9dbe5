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
