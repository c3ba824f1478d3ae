"""One writer per output: advisory locks on the folders (and files) a command writes.

A second command writing the same folder is refused in one line naming the first one's
process (or waits for it, where two jobs of one multirun need the same training). A kill
-9 leaves nothing that blocks the rerun: the operating system drops the lock with the
process, and the lock file goes with the folder's writer.
"""

from __future__ import annotations

import fcntl
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from bgap.common.errors import ConfigError
from bgap.common.runs import LOCK, METADATA, only_metadata

_HELD: dict[Path, int] = {}


@contextmanager
def exclusive(folder: str | Path, wait: bool = False) -> Iterator[None]:
    """Hold an advisory lock on ``folder`` while this process writes it. Another process
    holding it: refused in one line naming that process (``wait``: wait for it instead).
    Re-entrant within a process (``bgap.run`` locks the run folders its trainings lock). A
    folder this call created and left empty, or holding only the metadata of a command
    refused before it wrote anything (a setting found impossible once the traffic is built),
    is removed again, with the parents it created: the corrected command starts from
    nothing."""
    folder = Path(folder).resolve()
    if folder in _HELD:
        _HELD[folder] += 1
        try:
            yield
        finally:
            _HELD[folder] -= 1
        return
    made = [p for p in (folder, *folder.parents) if not p.exists()]  # innermost first
    folder.mkdir(parents=True, exist_ok=True)
    ended = True
    try:
        with _holding(folder / LOCK, folder, wait):
            _HELD[folder] = 1
            yield
    except Exception:  # refused; an interruption keeps its metadata, and says so
        ended = False
        raise
    finally:
        _HELD.pop(folder, None)
        _take_back(made, metadata_too=not ended)


def _take_back(made: list[Path], metadata_too: bool) -> None:
    """Remove the folders ``made`` that hold nothing (with ``metadata_too``: nothing but a
    command's metadata), innermost first; what a command wrote besides is never touched."""
    if not made:
        return
    if metadata_too and made[0].is_dir() and any(made[0].iterdir()) and only_metadata(made[0]):
        for name in METADATA:
            (made[0] / name).unlink(missing_ok=True)
    for folder in made:
        try:
            folder.rmdir()  # only if empty
        except OSError:
            return


@contextmanager
def all_exclusive(folders: Iterable[str | Path], wait: bool = False) -> Iterator[None]:
    """:func:`exclusive` on every folder, taken in one order (sorted), so that two commands
    locking overlapping sets cannot hold one each and wait for the other's."""
    with ExitStack() as held:
        for folder in sorted({Path(f).resolve() for f in folders}):
            held.enter_context(exclusive(folder, wait))
        yield


@contextmanager
def exclusive_file(path: str | Path) -> Iterator[None]:
    """Hold an advisory lock on the output file ``path`` (and the side files named after
    it) while this process writes them: ``.<name>.lock`` beside it, so that commands
    writing other files of the same folder do not wait on each other. Another process
    holding it: refused in one line naming that process."""
    path = Path(path).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    with _holding(path.with_name(f".{path.name}{LOCK}"), path, False):
        yield


@contextmanager
def _holding(lock: Path, what: Path, wait: bool) -> Iterator[None]:
    """The lock file ``lock`` held, naming this process, for writing ``what``."""
    handle = _lock(lock, what, wait)
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(f"process {os.getpid()} ({' '.join(sys.argv[:1] + sys.argv[1:3])})\n")
        handle.flush()
        yield
    finally:
        # removed while still held, so that no lock file is left in a finished folder (a
        # DVC output): a process waiting on this file sees it gone and locks the new one
        lock.unlink(missing_ok=True)
        fcntl.flock(handle, fcntl.LOCK_UN)
        handle.close()


def _lock(path: Path, what: Path, wait: bool) -> Any:
    """The lock file at ``path``, opened and locked; retried when the holder removed it
    meanwhile (the locked file must still be the one at the path)."""
    while True:
        handle = open(path, "a+")  # noqa: SIM115 - held open while locked
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "another process"
            handle.close()
            raise ConfigError(
                f"{what} is being written by {holder}; wait for it to finish or choose "
                "another output"
            ) from None
        try:
            same = os.fstat(handle.fileno()).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return handle
        handle.close()
