"""Where work runs (bgap.runner): jobs give the same results in the same order wherever they
run, Ctrl-C is a flag until pressed twice, a lost worker is one line, and the CPU kernels are
pinned by a command (not by ``import bgap``) unless ``reproducible=false``."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest

from bgap.common.errors import Interrupted
from bgap.runner.interrupt import CtrlC
from bgap.runner.jobs import run_jobs


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


def _exit_at(x: int, bad: int) -> int:
    if x == bad:
        os._exit(1)  # a worker killed (out of memory, kill -9)
    return x


def test_jobs_here_and_in_worker_processes_give_the_same_results_in_call_order():
    calls = [(x,) for x in range(7)]
    seen: list[int] = []
    here = run_jobs(_square_and_pid, calls, done=lambda k, r: seen.append(k))
    apart = run_jobs(_square_and_pid, calls, workers=2)
    assert [r for r, _ in here] == [r for r, _ in apart] == [x * x for x in range(7)]
    assert seen == list(range(7))
    assert {pid for _, pid in here} == {os.getpid()}
    assert os.getpid() not in {pid for _, pid in apart}


def test_a_worker_lost_is_one_line_saying_what_had_finished_and_what_was_kept():
    with pytest.raises(Interrupted) as stop:
        run_jobs(_exit_at, [(x, 0) for x in range(3)], workers=2, kept="rerun it")
    message = str(stop.value)
    assert message.startswith("a worker process was lost: ") and message.endswith("; rerun it")
    assert "of 3 jobs had finished" in message and "\n" not in message


def test_the_first_ctrl_c_raises_the_flag_and_the_second_interrupts():
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own
    try:
        _press_twice()
    finally:
        signal.signal(signal.SIGINT, before)


def _press_twice() -> None:
    with CtrlC() as ctrl_c:
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(1000):  # the handler runs between two bytecodes of this thread
            if ctrl_c.requested:
                break
        assert ctrl_c.requested
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


PROBE = """
import os, sys
sys.path.insert(0, {folder!r})
sys.argv = ["probe", *{args!r}]
from bgap.runner.numerics import command
command("probe")()
"""


@pytest.mark.parametrize(
    ("args", "kernels"),
    [([], "DEFAULT COMPATIBLE []"), (["reproducible=false", "x=1"], "None None ['x=1']")],
)
def test_a_command_pins_the_kernels_before_torch_loads_unless_told_not_to(tmp_path, args, kernels):
    (tmp_path / "probe.py").write_text(
        textwrap.dedent("""
        import os, sys
        def main():
            import torch
            cap = torch.backends.cpu.get_cpu_capability()
            pinned = os.environ.get("ATEN_CPU_CAPABILITY")
            print(cap if pinned else None, os.environ.get("MKL_CBWR"), sys.argv[1:])
    """)
    )
    env = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "MKL_CBWR")}
    done = subprocess.run(
        [sys.executable, "-c", PROBE.format(folder=str(tmp_path), args=args)],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == kernels


def test_import_bgap_sets_no_environment_variable():
    """None beyond what gymnasium itself sets on import (pygame's prompt)."""
    env = {k: v for k, v in os.environ.items() if k not in ("ATEN_CPU_CAPABILITY", "MKL_CBWR")}
    code = (
        "import os, gymnasium; before = dict(os.environ); import bgap; "
        "print(dict(os.environ) == before, os.environ.get('MKL_CBWR'))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert done.stdout.strip() == "True None", done.stderr


def test_a_bad_reproducible_value_is_one_line_and_status_2():
    done = subprocess.run(
        [sys.executable, "-m", "bgap.run", "reproducible=maybe"], capture_output=True, text=True
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "reproducible='maybe' must be true or false" in done.stderr


def _count_to(n: int, report) -> int:
    for i in range(1, n + 1):
        report(i)
    return n


def _count_if_told(n: int, report=None) -> str:
    if report is None:
        return "here"
    for i in range(1, n + 1):
        report(i)
    return "reported"


def test_jobs_in_workers_report_their_counts_to_one_bar_each():
    """Two jobs in worker processes send their step counts through the bars' queue: each
    bar ends at its own job's total, and disabled bars hand out no reporter."""
    from bgap.runner.progress import JobBars

    with JobBars(["a", "b"], [5, 7]) as bars:
        out = run_jobs(_count_to, [(5, bars.reporter(0)), (7, bars.reporter(1))], workers=2)
    assert out == [5, 7] and bars.counts == [5, 7]
    with JobBars(["a"], [1], enabled=False) as quiet:
        assert quiet.reporter(0) is None


def test_run_jobs_draws_a_bar_per_job_in_workers_and_hands_none_here(capfd):
    """``job_bars``: jobs in worker processes get a reporter and move their own bar to its
    total; the same jobs run here get ``report=None`` (they may draw their own)."""
    bars = [("a", 5), ("b", 7)]
    out = run_jobs(_count_if_told, [(5,), (7,)], workers=2, job_bars=bars)
    assert out == ["reported", "reported"]
    drawn = "".join(capfd.readouterr())
    assert "5/5" in drawn and "7/7" in drawn and "finished: a" in drawn, drawn
    assert run_jobs(_count_if_told, [(5,), (7,)], workers=1, job_bars=bars) == ["here"] * 2
    assert "5/5" not in capfd.readouterr().err


def test_run_jobs_counts_finished_work_on_one_bar(capfd):
    """``bar=(desc, unit, per_job)``: one bar moved ``per_job`` as each job finishes."""
    assert run_jobs(_square_and_pid, [(2,), (3,)], bar=("squares", "sq", 4))[0][0] == 4
    drawn = capfd.readouterr().err
    assert "squares" in drawn and "8/8" in drawn, drawn
