"""Pool workers do not outlive the process that started the pool (killed without cleanup)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, dead but not yet reaped by its new parent, counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "State:\tZ" not in state


def test_workers_exit_when_the_pool_owner_is_killed(tmp_path):
    script = tmp_path / "owner.py"
    script.write_text(
        "import os, sys, time\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        "from pipeline.process_pool import spawn_pool\n"
        "def pid_of_worker(_):\n"
        "    time.sleep(0.2)\n"
        "    return os.getpid()\n"
        "if __name__ == '__main__':\n"
        "    pool = spawn_pool(2)\n"
        "    print(' '.join(str(p) for p in sorted(set(pool.map(pid_of_worker, range(6))))), flush=True)\n"
        "    pool.submit(time.sleep, 600)\n"
        "    time.sleep(600)\n")
    workers: list[int] = []
    owner = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        workers = [int(p) for p in owner.stdout.readline().split()]
        assert workers and all(_alive(p) for p in workers)
        owner.send_signal(signal.SIGKILL)  # no cleanup at all: the pool is never shut down
        owner.wait(timeout=30)
        deadline = time.monotonic() + 20
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(p) for p in workers), "pool workers outlived their owner"
    finally:
        if owner.poll() is None:
            owner.kill()
        for p in workers:
            if _alive(p):
                os.kill(p, signal.SIGKILL)
