"""The error types that mean bad input (the command-line layer turns them into one line and
exit status 2), the check that raises the configuration one (and the seed blocks' check
built on it), and the check that refuses what this machine's memory cannot hold.

A leaf with no imports, so that CMetric (which stands alone on any trajectory file) and the
simulator schemas can validate their values the same way without importing each other.
"""

from __future__ import annotations

from typing import Any


class ConfigError(ValueError):
    """A configuration value is out of range; the message names the key and the fix."""


def check(ok: bool, key: str, value: Any, rule: str) -> None:
    """Raise :class:`ConfigError` naming ``key``, its ``value`` and the ``rule`` it breaks."""
    if not ok:
        raise ConfigError(f"{key}={value!r} is invalid: {rule}")


SEED_GAP = 10_000
"""How far apart two blocks of episode seeds start (validation, test, a search's own): a
block holds at most this many episodes, so blocks this far apart never share a seed."""


def check_apart(key: str, seed: int, other: int, what: str) -> None:
    """Refuse the seed block ``key=seed`` within :data:`SEED_GAP` of ``other``'s block
    (``what``: the other block and why the two must not share episodes)."""
    check(abs(seed - other) >= SEED_GAP, key, seed, f"must be at least {SEED_GAP} away from {what}")


def check_memory(nbytes: float, key: str, value: Any, fix: str) -> None:
    """Refuse a setting whose memory (``nbytes``, estimated before anything is allocated)
    exceeds what this machine has available: the out-of-memory killer ends a process with no
    message, and numpy's lazily zeroed arrays would let it start first."""
    import psutil  # imported here: the leaf's other checks need nothing

    available = psutil.virtual_memory().available
    if nbytes > available:
        need, have = nbytes / 2**30, available / 2**30
        raise ConfigError(
            f"{key}={value!r} needs about {need:,.1f} GiB, and this machine has {have:,.1f} "
            f"GiB available: {fix}"
        )


class TrajectoryError(ValueError):
    """A trajectory table cannot be read or scored; the message says what is wrong and how
    to fix it."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, with what the interrupted command saved and how to continue it."""
