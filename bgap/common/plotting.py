"""Plotting set-up shared by every command that draws a figure."""

from __future__ import annotations

from typing import Any


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend: figures go to files, no display is needed
    (a cluster node or CI has none). matplotlib is imported here, when a figure is drawn,
    not with the command: it takes about half a second and most calls draw nothing."""
    # Imported here: matplotlib takes ~0.5 s to import and most calls of a command draw nothing.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
