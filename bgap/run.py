"""The main job: ``python -m bgap.run env=dense mix=0.6 [profile=paper]``.

Trains (or reuses, when a finished run with the same config exists under ``root``) the
behaviour-rich policy and the default policy for the chosen density, evaluates both with
the scripted baselines on identical seeded episodes at the chosen mix and radius (or the
``grid``), prints a comparison table like the paper's bars and writes, under
``<root>/results/<name>/``: ``summary.csv`` / ``.json``, ``episodes.csv``,
``comparison.png``, ``config.yaml`` and ``command.txt``.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import asdict, replace
from pathlib import Path

from omegaconf import DictConfig

from bgap.config import ExperimentConfig, app, load
from bgap.evaluate import evaluate, format_table, plot_comparison, summarize, write_results
from bgap.runs import VOLATILE, digest, save_run_metadata
from bgap.train import run_dir_for, train, training_config
from bgap.vocab import POLICIES


def results_dir(cfg: ExperimentConfig) -> Path:
    """``out``, or a folder under ``<root>/results`` named by the main settings and a hash of
    all of them (reward, behaviour, backend, budget, ...), so runs of other settings never
    share a folder."""
    if cfg.out:
        return Path(cfg.out)
    settings = {k: v for k, v in asdict(cfg).items() if k not in VOLATILE}
    name = (
        f"{cfg.env.name}-mix{cfg.mix:g}-r{cfg.radius:g}-{cfg.grid.name}-{cfg.profile.name}"
        f"-s{cfg.seed}-{digest(settings)}"
    )
    return Path(cfg.root) / "results" / name


@contextmanager
def _exclusive(run_dir: Path):
    """An advisory lock on a run folder, held while it is trained or checked."""
    import fcntl

    run_dir.mkdir(parents=True, exist_ok=True)
    with open(run_dir / ".lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def run(cfg: ExperimentConfig, dcfg: DictConfig | None = None) -> Path:
    start = time.perf_counter()
    models = {}
    for policy in POLICIES:
        pcfg = training_config(cfg, policy)
        run_dir = run_dir_for(pcfg)
        # Parallel jobs of a multirun can need the same model (the default policy of a
        # density): one trains it, the others wait for it and reuse it.
        with _exclusive(run_dir):
            cached = (run_dir / "model.zip").exists()
            print(f"[{policy}] {'reusing' if cached else 'training'} {run_dir}")
            # resume=true: a training this command started and was interrupted continues
            models[policy] = str(train(replace(pcfg, resume=True)) / "model.zip")
    out = results_dir(cfg)
    if dcfg is not None:
        save_run_metadata(out, dcfg)
    policies = {**models, **{b: b for b in cfg.baselines}}
    episodes = evaluate(cfg, policies)
    summary = summarize(episodes)
    write_results(out, episodes, summary)
    title = f"{cfg.env.name}, behaviour {cfg.behavior.name}, {cfg.profile.name} profile"
    plot_comparison(summary, out / "comparison.png", title)
    print(format_table(summary))
    print(f"results in {out} ({time.perf_counter() - start:.0f} s)")
    return out


@app(
    "run",
    "bgap.run",
    "finished trainings are kept and reused by a rerun of the same command",
)
def main(dcfg: DictConfig) -> None:
    run(load(dcfg), dcfg)


if __name__ == "__main__":
    main()
