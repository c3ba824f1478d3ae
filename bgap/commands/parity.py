"""``bgap parity``: compare the vector backend with highway-env on the same seeded episodes."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from omegaconf import DictConfig
from tqdm.auto import tqdm

from bgap.common.cli import older_command_line
from bgap.common.config import app, load, validate
from bgap.common.errors import ConfigError, check
from bgap.common.runs import write_atomic
from bgap.common.tables import read_csv
from bgap.datasets.config import compose
from bgap.experiments.parity import SCHEMAS, ParityConfig, compare, plot, run
from bgap.runner.locks import exclusive
from bgap.traffic.scenario import env_config, fast_mode


@app(
    "parity",
    "bgap.parity",
    SCHEMAS,
    "the episodes played so far are in out/episodes.csv; add reuse=true to keep them",
)
def _hydra_main(dcfg: DictConfig) -> None:
    _parity(load(dcfg))


def main() -> None:
    """The Hydra app. The older command line still reads: ``--mixes 0,0.5,1``,
    ``--backends vector,highway``, ``--fast``, ``--reuse`` and the other ``--options``."""
    older_command_line(lists=("mixes", "backends"), flags=("fast", "reuse"))
    _hydra_main()


WRITTEN = ("episodes.csv", "parity.csv", "parity.png")
"""What :func:`main` writes into ``out``."""


def _kept_rows(path: Path, backends: list[str], mixes: list[float], seeds: list[int]):
    """``reuse=true``: the other backends' rows of an earlier ``episodes.csv``, refused unless
    they are the same episodes (mixes and seeds) this run plays."""
    old = read_csv(path)
    missing = {"seed", "mix", "backend"} - set(old.columns)
    if missing:
        raise ConfigError(
            f"{path} is not a bgap.parity episode table (no {sorted(missing)} "
            "column); give another out= or leave out reuse=true"
        )
    kept = old[~old.backend.isin(backends)]
    want = {(m, s) for m in mixes for s in seeds}
    for backend, rows in kept.groupby("backend"):
        if set(zip(rows.mix, rows.seed, strict=True)) != want:
            raise ConfigError(
                f"{path} holds {backend} episodes of other mixes or seeds than mixes="
                f"[{','.join(map(str, mixes))}] seed={seeds[0]} episodes={len(seeds)}; give "
                "those settings, or leave out reuse=true"
            )
    return kept


def _parity(args: ParityConfig) -> None:
    out = Path(args.out)
    if args.fast and out.resolve() == Path("results/parity").resolve():
        # its rows are labelled "vector": they must not replace the parity stage's results
        raise ConfigError(f"fast=true needs its own out= (got {args.out}): give a copy of it")
    backends, mixes = list(args.backends), list(args.mixes)
    seeds = list(range(args.seed, args.seed + args.episodes))
    earlier = [n for n in WRITTEN if (out / n).exists()]
    if earlier and not args.reuse:  # a rerun never overwrites an earlier result (the
        # pipeline's stage starts without them: DVC removes a stage's outputs first)
        raise ConfigError(
            f"{out} holds the results of an earlier run ({', '.join(earlier)}); "
            "give another out=, or reuse=true to keep its episodes"
        )
    frames = []
    if args.reuse and (out / "episodes.csv").exists():
        frames.append(_kept_rows(out / "episodes.csv", backends, mixes, seeds))
    compared = set(backends).union(*(set(f.backend) for f in frames))
    check(
        compared == {"vector", "highway"},
        "backends",
        args.backends,
        "parity compares both backends: give [vector,highway], or one of them with "
        "reuse=true of an out= holding the other's episodes",
    )
    with exclusive(out):
        for mix in tqdm(mixes, desc="mixes"):
            overrides = [f"env={args.env}", f"mix={mix}"]
            if args.duration:
                overrides.append(f"env.duration={args.duration}")
            config = env_config(validate(compose("simulate", overrides)))
            for backend in ("vector", "highway"):
                if backend not in backends:
                    continue
                fast = args.fast and backend == "vector"
                df = run(fast_mode(config) if fast else config, seeds, backend)
                df["mix"], df["backend"] = mix, backend
                frames.append(df)
                write_atomic(out / "episodes.csv", pd.concat(frames).to_csv(index=False))
        table = compare(pd.concat(frames))
        write_atomic(out / "parity.csv", lambda p: table.to_csv(p, index=False))
        plot(table, out / "parity.png")
    with pd.option_context("display.width", 160, "display.max_rows", 100):
        print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
