"""Ctrl-C and SIGTERM as a terminal and a scheduler send them, to a real command's processes:
while it loads, while its worker pool starts, to its workers alone and to it alone. Each
ends in one line and exit status 130, with no traceback and no process left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

pytestmark = pytest.mark.slow  # each starts a command and its pool: seconds apiece

# a pooled evaluation of about a minute (the highway backend, two workers)
EVALUATE = ["-m", "bgap.evaluate", "baselines=[idle,rule]", "grid=tiny", "backend=highway",
            "profile.eval_episodes=20", "workers=2"]  # fmt: skip


def _start(tmp_path) -> subprocess.Popen:
    """The command in a session of its own, as a terminal's foreground job is, and hearing
    Ctrl-C as one does (pytest-xdist's workers ignore SIGINT, and a child inherits that)."""
    return subprocess.Popen(
        [sys.executable, *EVALUATE, f"out={tmp_path / 'out'}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _workers(proc: subprocess.Popen, count: int, timeout: float = 60) -> list[psutil.Process]:
    """The command's child processes (its pool's workers and multiprocessing's resource
    tracker), once ``count`` workers have been spawned."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        children = psutil.Process(proc.pid).children()
        if sum("spawn_main" in " ".join(_cmdline(c)) for c in children) >= count:
            return children
        time.sleep(0.02)
    raise AssertionError(f"no {count} child processes after {timeout} s")


def _cmdline(process: psutil.Process) -> list[str]:
    try:
        return process.cmdline()
    except psutil.Error:  # ended meanwhile
        return []


def _ended(proc: subprocess.Popen, children: list[psutil.Process]) -> str:
    """The command's stderr, once it has ended with one interruption line and exit 130 and
    left no child process running."""
    _, err = proc.communicate(timeout=120)
    last = err.strip().splitlines()[-1]
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert last.startswith("bgap.evaluate: interrupted"), err
    _, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, alive
    return last


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_while_the_command_loads(sig, tmp_path):
    proc = _start(tmp_path)
    time.sleep(0.3)  # importing torch, SB3 and highway-env takes seconds
    os.killpg(proc.pid, sig)
    assert "nothing was written" in _ended(proc, [])
    assert not (tmp_path / "out").exists()


def test_ctrl_c_while_the_pool_starts(tmp_path):
    """The terminal's Ctrl-C reaches every process of the job, the workers while they
    still import."""
    proc = _start(tmp_path)
    children = _workers(proc, 1)  # the first worker is being spawned
    os.killpg(proc.pid, signal.SIGINT)
    assert "0 of 32 jobs had finished" in _ended(proc, children)


def test_sigterm_to_the_workers_alone(tmp_path):
    """A worker killed (the out-of-memory killer, a scheduler's stray signal): the command
    stops its other jobs and says so."""
    proc = _start(tmp_path)
    children = _workers(proc, 2)
    time.sleep(2)  # the workers are playing
    for child in children:
        child.send_signal(signal.SIGTERM)
    assert "a worker process was lost" in _ended(proc, children)


def test_sigterm_to_the_command_alone(tmp_path):
    """A scheduler's stop sent to the command's process only: its workers go with it."""
    proc = _start(tmp_path)
    children = _workers(proc, 2)
    time.sleep(2)
    proc.send_signal(signal.SIGTERM)
    assert "jobs had finished" in _ended(proc, children)
