"""``bgap watch``: render a policy (a zoo name or a model file) to a video."""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig

from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.runs import save_run_metadata
from bgap.experiments.watch import SCHEMAS, WatchConfig, default_out, own_settings, watch
from bgap.runner.locks import exclusive


@app("watch", "bgap.watch", SCHEMAS, "no video was finished; rerun the command")
def _main(dcfg: DictConfig) -> None:
    cfg: WatchConfig = load(dcfg)
    out = Path(cfg.out or default_out(cfg))
    with exclusive(out):
        save_run_metadata(out, dcfg)
        watch(cfg, out)


def main() -> None:
    """``python -m bgap.watch``: the policy's own settings go first on the command line, so
    that the user's override them."""
    args = sys.argv[1:]
    given = [a.split("=", 1)[1] for a in args if a.startswith("policy=")]
    if given and not any(a.startswith("-") for a in args):
        try:
            own = own_settings(given[-1])
        except (ConfigError, FileNotFoundError):
            own = []  # the command reports the policy in one line when it loads it
        sys.argv = [sys.argv[0], *own, *args]
    _main()
