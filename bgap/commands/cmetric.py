"""``python -m bgap.cmetric input=TRAJECTORIES [overrides]``: score every vehicle of a log.

    python -m bgap.cmetric input=data/dense/trajectories.parquet cmetric.mu=60 plot_vehicles=[3,7]
    python -m bgap.cmetric data/dense/trajectories.parquet     # a bare path means input=PATH

Writes into ``outputs/cmetric/<stem>_<preset>/`` (or the folder ``out=DIR/``; the input's
folder is never written to, so read-only data can be scored): ``<stem>_cmetric.csv``, one
row per vehicle with each style's mean SLE / SIE, the aggressiveness score and whether the
vehicle is flagged for having no evidence; ``<stem>_cmetric_windows.parquet`` (per window);
``<stem>_cmetric_centrality.png`` (closeness and degree over time of the chosen vehicles);
``config.yaml`` and ``command.txt``. A folder holding scores of other settings is refused.
``out=FILE.csv`` or ``out=FILE.parquet`` writes that file and its side files beside it
(``<stem>_config.yaml`` for the config).
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from bgap.cmetric import score_trajectories
from bgap.cmetric.config import SCHEMAS, CMetricAppConfig
from bgap.cmetric.io import check_scoreable, load_trajectories
from bgap.cmetric.score import label_auc
from bgap.common.cli import bare_first_argument
from bgap.common.config import app, load
from bgap.common.errors import ConfigError
from bgap.common.plotting import pyplot
from bgap.common.runs import other_settings, save_run_metadata, write_atomic
from bgap.runner.locks import exclusive, exclusive_file

USAGE = "usage: python -m bgap.cmetric input=TRAJECTORIES.(parquet|csv) [key=value ...]"


def plot_centrality(result, vehicle_ids, path: Path) -> None:
    plt = pyplot()

    cent = result.centrality
    episode = cent.episode.iloc[0]
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    scores = result.vehicles.set_index(["episode", "vehicle_id"])
    for vid in vehicle_ids:
        one = cent[(cent.episode == episode) & (cent.vehicle_id == vid)]
        row = scores.loc[(episode, vid)]
        name = f"vehicle {vid}"
        if "label" in row:
            name += f" ({row['label']})"
        name += f", A = {row['aggressiveness']:.2f}"
        axes[0].plot(one.time, one.closeness, label=name)
        axes[1].plot(one.time, one.degree, label=name)
    axes[0].set_ylabel("closeness centrality [1/m]")
    axes[1].set_ylabel("cumulative degree centrality")
    axes[1].set_xlabel("time [s]")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"CMetric centralities, episode {episode}")
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)


def score(cfg: CMetricAppConfig, dcfg: DictConfig) -> None:
    """Score ``cfg.input`` and write the scores, windows, plot and config."""

    if not cfg.input:
        raise ConfigError(f"input=None: give the trajectory table to score ({USAGE})")
    source = Path(cfg.input)
    as_file = cfg.out and not cfg.out.endswith("/") and not Path(cfg.out).is_dir()
    if as_file and Path(cfg.out).suffix not in (".csv", ".parquet"):
        raise ConfigError(
            f"out={cfg.out} is neither a folder nor a .csv/.parquet file; end a folder with /"
        )
    folder = (
        None if as_file else Path(cfg.out or f"outputs/cmetric/{source.stem}_{cfg.cmetric.name}")
    )
    out = Path(cfg.out) if as_file else folder / f"{source.stem}_cmetric.csv"
    stem = out.with_suffix("")
    windows, figure = Path(f"{stem}_windows.parquet"), Path(f"{stem}_centrality.png")
    settings = Path(f"{stem}_config.yaml")  # beside a file output; a folder has config.yaml
    written = [out, windows, figure, *([settings] if as_file else [])]
    for path in written:
        if path.resolve() == source.resolve():
            raise ConfigError(
                f"out={cfg.out} would write {path.name}, the input table; the scores go to "
                "another file"
            )
    table = load_trajectories(source, fps=cfg.fps)  # a bad table fails before anything is written
    check_scoreable(table)
    missing = sorted(set(cfg.plot_vehicles) - set(table.vehicle_id))
    if missing:
        shown = ", ".join(map(str, missing[:5])) + (" ..." if len(missing) > 5 else "")
        raise ConfigError(
            f"plot_vehicles={list(cfg.plot_vehicles)}: the table has no vehicle {shown}; plot "
            f"some of its {table.vehicle_id.nunique()} vehicles (its vehicle_id column) or "
            "leave plot_vehicles=[]"
        )
    with ExitStack() as held:
        if folder is not None:
            held.enter_context(exclusive(folder))
            save_run_metadata(folder, dcfg)  # refuses a folder of other settings before scoring
        else:  # a second command writing the same scores file is refused
            held.enter_context(exclusive_file(out))
            _refuse_other_scores(out, written, dcfg)
        result = score_trajectories(table, cfg.cmetric, fps=cfg.fps, progress=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        # each file whole or not at all (a kill leaves no half-written table)
        if out.suffix == ".parquet":
            write_atomic(out, lambda p: result.vehicles.to_parquet(p, index=False))
        else:
            write_atomic(out, result.vehicles.to_csv(index=False))
        write_atomic(windows, lambda p: result.windows.to_parquet(p, index=False))
        if as_file:
            write_atomic(settings, OmegaConf.to_yaml(dcfg, resolve=True))
        vehicles = result.vehicles
        chosen = list(cfg.plot_vehicles)
        if not chosen:
            first = vehicles[vehicles.episode == vehicles.episode.iloc[0]]
            ranked = first.sort_values("aggressiveness").vehicle_id.tolist()
            chosen = sorted(set(ranked[-2:] + ranked[:2]))
        plot_centrality(result, chosen, figure)
    flagged = int(vehicles.flagged.sum())
    print(f"scored {len(vehicles)} vehicles ({flagged} flagged: no evidence) -> {out}")
    if "label" in vehicles:
        print(vehicles.groupby("label").aggressiveness.describe().to_string())
        try:
            print(f"ROC AUC (aggressive vs conservative): {label_auc(vehicles):.3f}")
        except ValueError:
            pass


def _refuse_other_scores(out: Path, written: list[Path], dcfg: DictConfig) -> None:
    """A scores file and its side files (``written``) may be rewritten only by the same
    settings: ones that hold scores of other settings, or files no bgap command wrote (no
    ``<stem>_config.yaml`` beside them), are refused."""
    stored = out.with_name(f"{out.stem}_config.yaml")
    if not stored.exists():
        there = [p.name for p in written if p.exists()]
        if there:
            raise ConfigError(
                f"out={out}: {', '.join(there)} exist(s) and bgap.cmetric did not write "
                "them; choose a new file name"
            )
        return
    differs = other_settings(stored, OmegaConf.to_container(dcfg, resolve=True), ("out",))
    if differs:
        raise ConfigError(
            f"out={out} holds scores of other settings ({differs}); choose another file"
        )


@app("cmetric_app", "bgap.cmetric", SCHEMAS, "nothing was written; rerun the command")
def _hydra_main(dcfg: DictConfig) -> None:
    score(load(dcfg), dcfg)


def main() -> None:
    """The Hydra app; a first argument without ``=`` (the old form) is taken as ``input=``."""
    bare_first_argument("input")
    _hydra_main()


if __name__ == "__main__":
    main()
