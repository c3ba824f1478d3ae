"""The CPU kernels a command computes with: pinned, so that torch does not pick them by the
instruction set it finds, unless the command line says ``reproducible=false``; and a
command's start, where Ctrl-C ends it in one line.

torch picks its CPU kernels by the instruction set it finds (AVX-512 or AVX2 vectorised
loops, MKL's per-ISA GEMM paths), and their float sums differ in the last bits, which a
training amplifies: the same 6,000-step training ends with other weights on an AVX-512
machine than on the one the study was trained on. Pinned, the same seed gives the same
numbers on one machine; trainings still differ between some machines for a cause not yet
found (docs/notes), so a trained number is checked on the machine that trained it. Both
variables are read when torch loads, so :func:`pin` runs in a command's entry module,
before anything imports torch.
Importing bgap as a library pins nothing: numerics are the caller's choice.
Measured cost (docs/benchmarks.md): about 10% of an SB3 training, 4.5x for the batched
learner's stacked matrix products.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from importlib import import_module

PINNED = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE"}
"""The kernels every bgap command uses unless told otherwise (a variable the user set
already is kept)."""

SETTING = "reproducible"
"""The command-line setting that turns the pinning off (``reproducible=false``)."""


def pin(argv: list[str] | None = None) -> bool:
    """Pin the kernels (:data:`PINNED`) unless ``argv`` (default: ``sys.argv``) holds
    ``reproducible=false``. The setting is taken out of ``argv`` (the command's own
    settings do not know it); a run folder's ``command.txt`` records the command as typed,
    with it. Returns whether the kernels are pinned."""
    args = sys.argv if argv is None else argv
    given = [a for a in args[1:] if a.split("=", 1)[0].lstrip("+") == SETTING]
    value = given[-1].partition("=")[2].strip().lower() if given else "true"
    if value not in ("true", "false"):
        prog = os.path.basename(args[0]) if args else "bgap"
        print(
            f"{prog}: {SETTING}={value!r} must be true or false (false: this machine's "
            "fastest kernels, whose numbers may differ from another's)",
            file=sys.stderr,
        )
        raise SystemExit(2)
    if given:
        args[:] = [args[0], *(a for a in args[1:] if a not in given)]
    if value == "false":
        return False
    for name, kernel in PINNED.items():
        os.environ.setdefault(name, kernel)
    return True


def pinned() -> dict[str, str]:
    """The pinning variables as this process has them: what worker processes on other
    machines (Ray tasks) are started with."""
    return {name: os.environ[name] for name in PINNED if name in os.environ}


def command(module: str) -> Callable[[], None]:
    """A command's entry (``main`` of ``module``) that pins the kernels (:func:`pin`) before
    it imports ``module``, which loads torch: what ``python -m bgap.<command>`` runs."""

    def main() -> None:
        pin()
        entry = _load(module)
        entry()

    return main


def _load(module: str) -> Callable[[], None]:
    """``module``'s ``main``, imported with Ctrl-C and SIGTERM ending the command in one line
    (its imports take seconds, before the command's own handling, :func:`bgap.common.cli.run`,
    is in place)."""
    prog = "bgap." + module.rsplit(".", 1)[-1]
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        return import_module(module).main
    except KeyboardInterrupt:
        message = "interrupted while starting: nothing was written; run the same command again"
        print(f"{prog}: {message}", file=sys.stderr)
        raise SystemExit(130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
