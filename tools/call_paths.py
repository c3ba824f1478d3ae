"""How often a command's calls cross between the study and the plumbing.

    python tools/call_paths.py                        # the main job at the tiny profile
    python tools/call_paths.py bgap.evaluate baselines=[idle] ...

Runs the command in this process under ``sys.setprofile`` and counts the distinct
caller -> callee edges (module.function to module.function) whose two ends lie on different
sides: the plumbing (``bgap.common``, ``bgap.runner``: configs, run folders, locks, pools,
Ray, Ctrl-C) and the study (every other bgap package). Work done in worker processes is not
traced, only the command's own process. To measure an older commit, run this file with
that commit's tree first on the path: ``PYTHONPATH=<worktree> python tools/call_paths.py``
from inside the worktree.
"""

from __future__ import annotations

import runpy
import sys
import threading
from collections import Counter
from types import FrameType
from typing import Any

PLUMBING = ("bgap.common", "bgap.runner")
"""The packages on the plumbing side."""
MAIN_JOB = ["bgap.run", "profile=tiny", "profile.eval_episodes=4", "grid=tiny"]
"""The main job at the tiny profile: the default command."""


def side(module: str) -> str | None:
    """``plumbing``, ``study`` or None (not bgap's)."""
    if module != "bgap" and not module.startswith("bgap."):
        return None
    return "plumbing" if module.startswith(PLUMBING) else "study"


def crossings(argv: list[str]) -> set[tuple[str, str]]:
    """The distinct crossing edges while ``argv`` (a module and its arguments) runs."""
    edges: set[tuple[str, str]] = set()

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        if event != "call" or frame.f_back is None:
            return
        callee, caller = (
            frame.f_globals.get("__name__", ""),
            frame.f_back.f_globals.get("__name__", ""),
        )
        a, b = side(caller), side(callee)
        if a and b and a != b:
            edges.add(
                (f"{caller}.{frame.f_back.f_code.co_name}", f"{callee}.{frame.f_code.co_name}")
            )

    sys.argv = list(argv)
    threading.setprofile(profile)
    sys.setprofile(profile)
    try:
        runpy.run_module(argv[0], run_name="__main__", alter_sys=True)
    except SystemExit as done:
        if done.code not in (0, None):
            raise
    finally:
        sys.setprofile(None)
        threading.setprofile(None)  # type: ignore[arg-type]
    return edges


def main() -> None:
    argv = sys.argv[1:] or MAIN_JOB
    edges = crossings(argv)
    ways = Counter(
        "study -> plumbing" if side(a.rsplit(".", 1)[0]) == "study" else "plumbing -> study"
        for a, _ in edges
    )
    for a, b in sorted(edges):
        print(f"{a} -> {b}", file=sys.stderr)
    print(f"{len(edges)} distinct crossing edges ({dict(ways)}) during python -m {' '.join(argv)}")


if __name__ == "__main__":
    main()
