"""How every command meets its user: one line per known mistake, one line per interruption.

Every ``python -m bgap.<command>`` runs through :func:`run`: a bad value, an unknown key, a
missing file or a defective trajectory table ends the command with one line on stderr (what
is wrong, the offending value, how to fix it) and exit status 2, never a traceback; Ctrl-C
or SIGTERM (a scheduler's or ``kill``'s stop) ends it with one line saying what was saved
and how to continue, exit status 130. A machine fault (a full disk, a read-only folder) is
one line and exit status 2. Errors that are not known mistakes (bugs) keep their traceback.
"""

from __future__ import annotations

import errno
import os
import shlex
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any, NoReturn

from bgap.common.errors import ConfigError, Interrupted, TrajectoryError

BAD_INPUT = 2
INTERRUPTED = 130

ENV_COMMAND = "BGAP_COMMAND"
"""The bgap command a process works for, set by :func:`run` in the command's own process and
inherited by the processes it starts (Ray tasks get it from their driver): what a run
folder's ``command.txt`` records, not a worker's own command line."""


def own_command() -> str:
    """This process's command line as typed (``sys.orig_argv`` keeps ``-m bgap.x``, where
    ``argv[0]`` would be the module's file path)."""
    return " ".join(shlex.quote(a) for a in ["python", *sys.orig_argv[1:]])


def command() -> str:
    """The bgap command this process works for: its own, or, in a worker process or a Ray
    task, the command that started it (:data:`ENV_COMMAND`)."""
    return os.environ.get(ENV_COMMAND) or own_command()


def one_line(err: BaseException) -> str:
    """An exception (and its cause) as one line: Hydra's and OmegaConf's messages span
    several lines and end with the config search path, which a user does not need."""
    text = str(err)
    cause = err.__cause__ or (None if err.__suppress_context__ else err.__context__)
    if cause is not None and str(cause) not in text:
        text += "\n" + str(cause)
    parts: list[str] = []
    for line in (raw.strip() for raw in text.splitlines()):
        if line.startswith(("Config search path", "Set the environment variable HYDRA")):
            break
        if not line or line.startswith(("full_key:", "object_type", "reference_type")):
            continue
        parts.append(line)
    return " ".join(parts)


def fail(prog: str, message: str, status: int = BAD_INPUT) -> NoReturn:
    print(f"{prog}: {message}", file=sys.stderr)
    raise SystemExit(status)


def known_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean bad input, not a bug."""
    # Imported here: Hydra is imported by the commands that compose a config, not by this leaf.
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    return (
        ConfigError,
        TrajectoryError,
        FileNotFoundError,
        NotADirectoryError,
        IsADirectoryError,
        PermissionError,
        HydraException,
        OmegaConfBaseException,
    )


def run(prog: str, task: Callable[[], Any], on_interrupt: str) -> Any:
    """Run ``task`` with the one-line error style; ``on_interrupt`` says what a Ctrl-C keeps
    (an :class:`~bgap.common.errors.Interrupted` raised by the task says it instead)."""
    os.environ[ENV_COMMAND] = own_command()  # for the worker processes it starts
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _as_ctrl_c) if main else None
    try:
        return task()
    except Interrupted as err:
        fail(prog, f"interrupted: {err}", INTERRUPTED)
    except KeyboardInterrupt:
        fail(prog, f"interrupted: {on_interrupt}", INTERRUPTED)
    except FileExistsError as err:  # a file where the command makes its folder
        fail(
            prog,
            f"{err.filename} is a file, not a folder: give the output (out=, run_dir=) "
            "a folder's path, or move that file",
        )
    except known_errors() as err:
        fail(prog, one_line(err))
    except OSError as err:
        if err.errno not in FAULTS:
            raise  # not a fault of the machine: a bug, with its traceback
        fail(prog, machine_fault(err))
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)


def _as_ctrl_c(signum: int, frame: Any) -> None:
    """SIGTERM goes where Ctrl-C goes: to the running work's flag (a training stops between
    two updates and keeps its checkpoint) or, with none, a ``KeyboardInterrupt``."""
    handler = signal.getsignal(signal.SIGINT)
    if not callable(handler):  # ignored or the system's default: stop here
        raise KeyboardInterrupt
    handler(signal.SIGINT, frame)


FAULTS = {
    errno.ENOSPC: "no space left on the device{writing}: free some",
    errno.EDQUOT: "the disk quota is used up{writing}: free some",
    errno.EROFS: "{file} is on a read-only file system: give the output (out=, root=) a "
    "writable folder",
}
"""The machine faults a command reports in one line (errno: what happened, and the fix;
``{writing}`` names the file where the error does, ``{file}`` is the file or "the output")."""


def machine_fault(err: OSError) -> str:
    """The one line for a machine fault (an ``OSError`` whose errno is in :data:`FAULTS`)."""
    writing = f" writing {err.filename}" if err.filename else ""
    what = FAULTS[err.errno].format(writing=writing, file=err.filename or "the output")
    return (
        f"{what}, and run the same command again (what was finished is kept or redone, "
        "never half-read)"
    )


def bare_first_argument(*keys: str) -> None:
    """Read the leading command-line arguments without ``=`` (``python -m bgap.cmetric
    PATH``, ``python -m bgap.datasets highd PATH``) as ``key=<it>``, one key each in order,
    before Hydra parses the rest."""
    for i, key in enumerate(keys, start=1):
        if len(sys.argv) <= i or "=" in sys.argv[i] or sys.argv[i].startswith("-"):
            return
        sys.argv[i] = f"{key}={sys.argv[i]}"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


HYDRA_OPTIONS = (
    "--help",
    "-h",
    "--hydra-help",
    "--cfg",
    "-c",
    "--info",
    "--resolve",
    "--package",
    "-p",
    "--multirun",
    "-m",
    "--run",
    "-r",
    "--version",
)
"""Hydra's own command-line options: passed through as they are."""


def older_command_line(
    positional: str = "",
    listed: bool = False,
    lists: tuple[str, ...] = (),
    flags: tuple[str, ...] = (),
    renamed: dict[str, str] | None = None,
) -> None:
    """Rewrite ``sys.argv`` of a command's older ``--option`` form (argparse) into Hydra's
    ``key=value`` overrides, so scripts written for it keep working: leading arguments
    without ``=`` are ``positional`` (a list when ``listed``), ``--name VALUE`` is
    ``name=VALUE`` (for a ``lists`` key, ``name=[...]`` of every comma-separated value after
    it), and ``--name`` of ``flags`` is ``name=true``; ``-`` in a name is ``_``, and a name
    in ``renamed`` takes its new name. Hydra's own options (:data:`HYDRA_OPTIONS`) pass
    through."""
    args: list[str] = []
    bare: list[str] = []
    key = None
    for arg in sys.argv[1:]:
        value = "=" not in arg and (not arg.startswith("-") or _is_number(arg))
        name = arg[2:].replace("-", "_") if arg.startswith("--") and "=" not in arg else None
        name = (renamed or {}).get(name, name) if name else name
        if arg in HYDRA_OPTIONS or (name is None and not value) or (name and arg[2:3] == "-"):
            args.append(arg)
            key = None
        elif name in flags:
            args.append(f"{name}=true")
            key = None
        elif name is not None:
            key = name
            args.append(f"{name}=[]" if name in lists else f"{name}=")
        elif key in lists:
            items = [x for x in args[-1][len(key) + 2 : -1].split(",") if x]
            args[-1] = f"{key}=[{','.join(items + arg.split(','))}]"
        elif key is not None:
            args[-1], key = f"{key}={arg}", None
        elif positional and not args:
            bare.append(arg)
        else:
            args.append(arg)
    if bare:
        args[:0] = (
            [f"{positional}=[{','.join(bare)}]"]
            if listed
            else [f"{positional}={bare[0]}", *bare[1:]]
        )
    sys.argv[1:] = args
