"""Run folders: every run saves its resolved config and the command that made it.

Written by hand rather than by Hydra's output handling (``hydra.run.dir`` and ``.hydra/``,
switched off in the packaged configs): a training's run folder is named from the validated
config itself (a hash of everything that changes what is learnt), which Hydra's
interpolations cannot compute before the config exists, and one command writes several run
folders (``bgap.run``: both policies and the results).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf


def save_run_metadata(out_dir: str | Path, cfg: Any) -> Path:
    """Write ``config.yaml`` (resolved) and ``command.txt`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    conf = cfg if OmegaConf.is_config(cfg) else OmegaConf.structured(cfg)
    (out / "config.yaml").write_text(OmegaConf.to_yaml(conf, resolve=True))
    # orig_argv keeps "-m bgap.x"; argv[0] would be the module's file path.
    command = " ".join(shlex.quote(a) for a in ["python", *sys.orig_argv[1:]])
    (out / "command.txt").write_text(command + "\n")
    return out
