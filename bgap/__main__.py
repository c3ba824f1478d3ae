"""``bgap <command> [key=value ...]`` (or ``python -m bgap <command>``): one entry point for
every command; ``bgap`` alone lists them, ``bgap --version`` prints the installed version.
``bgap train ...`` is ``python -m bgap.train ...``."""

from __future__ import annotations

import runpy
import sys
from difflib import get_close_matches

COMMANDS = {
    "simulate": ("bgap.simulate", "record behaviour-rich traffic as a trajectory table"),
    "datasets": ("bgap.datasets", "convert SUMO, highD or NGSIM traffic to bgap's table"),
    "cmetric": ("bgap.cmetric", "score any trajectory table for driving style (CMetric)"),
    "cmetric.search": ("bgap.cmetric.search", "tune CMetric's parameters on labelled tables"),
    "cmetric.boundary": ("bgap.cmetric.boundary", "fix CMetric's aggressive/conservative boundary"),
    "calibrate": ("bgap.calibrate", "fit the driver classes to CMetric targets or to data"),
    "train": ("bgap.train", "train navigation policies (one or many seeds, resumable)"),
    "evaluate": ("bgap.evaluate", "evaluate models and baselines on seeded episodes"),
    "run": ("bgap.run", "the main job: train both policies, evaluate, compare"),
    "sweep": ("bgap.sweep", "Optuna search over reward or learner settings"),
    "recipe": ("bgap.recipe", "search the training recipe and check it on more seeds"),
    "tune_rule": ("bgap.tune_rule", "tune the rule-based ego's IDM and MOBIL on validation"),
    "parity": ("bgap.parity", "compare the vector backend with highway-env"),
    "figures": ("bgap.figures", "the study's figures, claims and results page"),
    "zoo": ("bgap.zoo", "export trained run folders into the zoo (kept in git)"),
    "watch": ("bgap.watch", "render a policy (zoo name or model file) to a video"),
    "select": ("bgap.select", "keep the best of each group of training seeds on validation"),
    "pipeline": ("bgap.pipeline", "save or restore a search's trial log (trials save|restore)"),
}


TOOLS = {"bench": "python tools/bench.py"}
"""Commands that became developer tools in the checkout (``tools/``), outside the library."""


def version() -> str:
    """The installed distribution's version (its metadata), else the package's own
    ``bgap.__version__`` (a source tree that was never installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("bgap")
    except PackageNotFoundError:
        from bgap import __version__

        return __version__


def usage() -> str:
    width = max(map(len, COMMANDS))
    lines = [f"  {name:<{width}}  {about}" for name, (_, about) in COMMANDS.items()]
    return (
        "usage: bgap <command> [key=value ...]   (--help after a command: its options)\n"
        "       bgap --version\n\n"
        "commands:\n" + "\n".join(lines)
    )


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return
    if args[0] in ("-V", "--version"):
        print(f"bgap {version()}")
        return
    name = args[0].replace("-", ".") if args[0] not in COMMANDS else args[0]
    if name not in COMMANDS:
        close = get_close_matches(args[0], list(COMMANDS), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        if name in TOOLS:
            hint = f"it is a developer tool now: {TOOLS[name]} in a checkout; "
        print(f"bgap: unknown command {args[0]!r}; {hint}`bgap` lists them", file=sys.stderr)
        raise SystemExit(2)
    module = COMMANDS[name][0]
    sys.argv = [f"bgap {name}", *args[1:]]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
