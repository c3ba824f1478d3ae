"""The error types that mean bad input (the command-line layer turns them into one line and
exit status 2), and the check that raises the configuration one.

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


class TrajectoryError(ValueError):
    """A trajectory table cannot be read or scored; the message says what is wrong and how
    to fix it."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, with what the interrupted command saved and how to continue it."""
