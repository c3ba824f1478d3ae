"""What the developer tools share: a one-line argparse (the library's commands speak Hydra)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any, NoReturn

from bgap.common.cli import fail


class OneLineParser(argparse.ArgumentParser):
    """argparse for the developer tools' ``--options`` (bench, relock): a bad option is one
    line and exit status 2, as with every bgap command (which speak Hydra)."""

    def error(self, message: str) -> NoReturn:
        fail(self.prog, f"{message} (python {self.prog} --help lists the options)")


def positive(kind: type = float) -> Callable[[str], Any]:
    """An argparse type: a finite number > 0 (``kind``: float or int)."""

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{text!r} must be a finite number > 0")
        return value

    return parse
