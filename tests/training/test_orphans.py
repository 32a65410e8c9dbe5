"""Workers die with their parent: ``kill -9`` of a parent leaves no member or rollout worker
(and no resource tracker) running on.

Each test starts a parent Python process that starts workers and records their pids in files,
SIGKILLs the parent, then polls ``/proc`` until the workers are gone.  The deadline is a
liveness bound far above the watchdog's 1 s period (the old code left them running for
minutes), not a timing measurement.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from excavator_surrogate.orphans import ORPHAN_EXIT, parent_args

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc (Linux)")

ROOT = Path(__file__).resolve().parents[2]
DEADLINE_S = 20.0

MEMBERS_PARENT = """
import os, sys, threading, time
from pathlib import Path

from excavator_surrogate.data.dataset import Dataset
from excavator_surrogate.io_utils import write_text
from excavator_surrogate.surrogate.synthetic import synthetic_spec
from excavator_surrogate.training import TrainConfig
from excavator_surrogate.training.jobs import TrainJob, run_jobs


def busy_member(job, show_progress):
    # a member that trains to a long budget: it never talks to the parent before the end;
    # its pid file appears whole (written atomically), or the recorder could read it empty
    write_text(job.out / "pid", str(os.getpid()))
    time.sleep(600)
    return job.out / "best.pt"


def record(root, jobs):
    from multiprocessing import resource_tracker

    try:
        while not all((j.out / "pid").exists() for j in jobs):
            time.sleep(0.05)
        pids = [int((j.out / "pid").read_text()) for j in jobs]
        pids.append(resource_tracker._resource_tracker._pid)
        write_text(root / "pids", " ".join(map(str, pids)))
    except BaseException:  # the test sees the parent fail now, not at its 120-s bound
        import traceback

        traceback.print_exc()
        os._exit(3)


if __name__ == "__main__":
    root = Path(sys.argv[1])
    jobs = [TrainJob(TrainConfig(), Dataset(spec=synthetic_spec(2)), root / f"m{i}") for i in range(2)]
    for j in jobs:
        j.out.mkdir()
    threading.Thread(target=record, args=(root, jobs), daemon=True).start()
    run_jobs(busy_member, jobs, workers=2)
"""

ROLLOUT_PARENT = """
import sys, time
from pathlib import Path

import numpy as np

from excavator_surrogate.control.workers import RolloutWorker
from excavator_surrogate.env.engine import SurrogateEngine
from excavator_surrogate.io_utils import write_text
from tests.helpers.surrogates import tiny_surrogate

if __name__ == "__main__":
    root = Path(sys.argv[1])
    sur = tiny_surrogate()
    worker = RolloutWorker(sur, n_batch=1)
    engine = SurrogateEngine(sur, n_envs=1)
    engine.reset(np.zeros((1, sur.spec.n_joint)))
    n_u = sur.spec.n_u
    # a long rollout: the worker is busy, not waiting on the pipe, when the parent dies
    worker.submit(engine.export_row(0), np.zeros((1, 1_000_000, n_u), np.float32))
    time.sleep(1.0)
    write_text(root / "pids", str(worker._proc.pid))
    time.sleep(600)
"""


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def _kill_parent_and_wait(script: str, tmp_path: Path) -> list[int]:
    """Run ``script`` as a parent process, SIGKILL it once it wrote ``pids``; returns the pids
    still alive at the deadline (killed afterwards, so nothing outlives the test)."""
    # a killed parent cannot remove its multiprocessing temp folder: give it its own, short
    # (it holds AF_UNIX sockets), and remove it afterwards
    scratch = Path(tempfile.mkdtemp(prefix="exsur-test-"))
    try:
        return _run_and_kill(script, tmp_path, scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _run_and_kill(script: str, tmp_path: Path, scratch: Path) -> list[int]:
    path = tmp_path / "parent.py"
    path.write_text(textwrap.dedent(script))
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        "TMPDIR": str(scratch),
    }
    parent = subprocess.Popen([sys.executable, str(path), str(tmp_path)], cwd=ROOT, env=env)
    try:
        t0 = time.monotonic()
        while not (tmp_path / "pids").exists():
            assert parent.poll() is None, f"the parent process failed (rc {parent.returncode})"
            assert time.monotonic() - t0 < 120, "the parent never started its workers"
            time.sleep(0.1)
        pids = [int(p) for p in (tmp_path / "pids").read_text().split()]
        assert all(_alive(p) for p in pids)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    t0 = time.monotonic()
    while any(_alive(p) for p in pids) and time.monotonic() - t0 < DEADLINE_S:
        time.sleep(0.2)
    left = [p for p in pids if _alive(p)]
    for p in left:  # do not leave them running if the test fails
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return left


def test_member_workers_and_resource_tracker_die_with_a_killed_parent(tmp_path):
    assert _kill_parent_and_wait(MEMBERS_PARENT, tmp_path) == []


def test_a_busy_rollout_worker_dies_with_a_killed_parent(tmp_path):
    assert _kill_parent_and_wait(ROLLOUT_PARENT, tmp_path) == []


def test_die_with_parent_exits_at_once_when_the_parent_is_already_gone(tmp_path):
    """The race of a parent that died before the worker armed its watch: a child told that
    its parent is another pid exits with ORPHAN_EXIT right away."""
    code = (
        "from excavator_surrogate.orphans import die_with_parent\n"
        "import os, time\n"
        "die_with_parent(os.getppid() + 100000, True)\n"
        "time.sleep(60)\n"
    )
    rc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=60).returncode
    assert rc == ORPHAN_EXIT


def test_parent_args_name_this_process_and_thread():
    pid, main = parent_args()
    assert pid == os.getpid() and main is True
