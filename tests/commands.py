"""Running a command's ``main`` in this process, as ``python -m`` would, for the tests."""

from __future__ import annotations

import importlib
import sys


def command(module: str, args: list[str], monkeypatch, capsys) -> tuple[int, str, str]:
    """Exit status (0 when ``main`` returns), stdout and stderr of ``python -m module args``."""
    main = importlib.import_module(module).main
    monkeypatch.setattr(sys, "argv", [module, *args])
    try:
        main()
        status = 0
    except SystemExit as stop:
        status = stop.code
    out = capsys.readouterr()
    return status, out.out, out.err
