"""Progress bars for jobs that run in other processes: each job sends its own count (steps,
episodes) through a queue, and a thread here draws one bar per job, with its rate and time
left.

Why a queue: a pool's worker cannot draw on the parent's terminal without garbling the
other workers' bars, and a bar that counts finished jobs sits at 0% for as long as the
first job lasts.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Any

from tqdm import tqdm


@dataclass(frozen=True)
class Reporter:
    """Job ``k``'s line to the parent's bars (picklable: it travels to a pool's worker)."""

    queue: Any
    k: int

    def __call__(self, count: int, start: bool = False) -> None:
        """Job ``k`` has reached ``count`` (a total, not an increment); ``start``: it starts
        there (a resumed job), which the rate and time left leave out."""
        self.queue.put((self.k, int(count), start))


class JobBars:
    """One bar per job (``names``, ``totals``) while the ``with`` block runs;
    :meth:`reporter` gives job ``k`` its :class:`Reporter` (``None`` when disabled)."""

    def __init__(
        self, names: Sequence[str], totals: Sequence[int], unit: str = "step", enabled: bool = True
    ) -> None:
        self.names, self.totals, self.unit, self.enabled = list(names), list(totals), unit, enabled
        self._queue: Any = None
        self.counts = [0] * len(self.names)
        """Each job's last count reported."""

    def __enter__(self) -> JobBars:
        if self.enabled:
            self._manager = get_context("spawn").Manager()
            self._queue = self._manager.Queue()
            self._bars = [
                tqdm(total=t, desc=n, unit=self.unit, position=k, dynamic_ncols=True)
                for k, (n, t) in enumerate(zip(self.names, self.totals, strict=True))
            ]
            self._thread = threading.Thread(target=self._draw, daemon=True)
            self._thread.start()
        return self

    def reporter(self, k: int) -> Reporter | None:
        return Reporter(self._queue, k) if self.enabled else None

    def write(self, line: str) -> None:
        """A line above the bars (or plain, when disabled)."""
        tqdm.write(line) if self.enabled else print(line)

    def _draw(self) -> None:
        while (item := self._queue.get()) is not None:
            k, count, start = item
            bar = self._bars[k]
            self.counts[k] = count
            if start:
                bar.reset(total=bar.total)
                bar.initial = bar.n = bar.last_print_n = count
                bar.refresh()
            else:
                bar.update(count - bar.n)

    def __exit__(self, *exc: object) -> None:
        if not self.enabled:
            return
        self._queue.put(None)
        self._thread.join()
        for bar in self._bars:
            bar.close()
        self._manager.shutdown()
