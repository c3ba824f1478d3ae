"""Why hand-built egos crash early: the crash rate in an episode's first policy steps
against later windows, and, episode by episode, whether the crash was the ego's own doing.

Reads the baselines' evaluation (``results/evaluation/baselines/paper`` by default: every
mix, radius and episode seed of the study's grid). Per ego and density, pooled over radii and
mixes: the share of episodes with a crash in the first :data:`EARLY` policy steps, and the
crash rate per later window of :data:`EARLY` steps (crashes after step :data:`EARLY` over
the windows the episodes lasted beyond it), and their ratio.

Then, for every early crash, three checks on the same episode (same cell and episode seed):

- **replayed**: the ego replayed from the evaluation's own settings crashes at the recorded
  step (the settings and the seed are the episode's: the checks below are about it);
- **IDM survives**: IDM in its lane, which the same evaluation played on the same episode,
  lasted past step :data:`EARLY` (read from the table, no simulation);
- **actions that survive**: of the five meta-actions, how many held for the first
  :data:`EARLY` steps (then the ego's own policy) end them without a collision.

An early crash whose episode some meta-action survives started feasibly: the crash is the
ego's decision (its ending, the partner's side, says which: a lane change or a rear-end).

    python tools/early_crashes.py [EVALUATION_FOLDER] [CSV_OUT]
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import OmegaConf

from bgap.agents.policies import baseline
from bgap.common.config import validate
from bgap.common.runs import CONFIG
from bgap.experiments.config import compose
from bgap.experiments.evaluate import Cell, cell_env_config
from bgap.sim.rollout import rollout

EARLY = 3
"""Policy steps counted as an episode's start (the results page's crash-timing table)."""
EGOS = ("rule", "rule_tuned", "idle")
"""The hand-built egos checked (IDM in its lane crashes too rarely early to need it)."""
ACTIONS = 5


def rates(df: pd.DataFrame) -> pd.DataFrame:
    """Per ego and density: episodes, early crashes and the early share, later crashes and
    the rate per later window of EARLY steps, and the ratio of the two."""
    rows = []
    for (policy, density), g in df.groupby(["policy", "density"], sort=True):
        crashed = g.crashed.astype(bool)
        early = int((crashed & (g.steps <= EARLY)).sum())
        later = int((crashed & (g.steps > EARLY)).sum())
        windows = float((np.clip(g.steps - EARLY, 0, None) / EARLY).sum())
        share, per_window = early / len(g), later / windows if windows else float("nan")
        rows.append(
            {
                "ego": policy,
                "density": density,
                "episodes": len(g),
                f"crashes in steps 1-{EARLY}": early,
                "early share %": 100 * share,
                "later crashes": later,
                f"later rate per {EARLY}-step window %": 100 * per_window,
                "ratio": share / per_window if later else float("nan"),
            }
        )
    return pd.DataFrame(rows)


def held_then(action: int, then) -> callable:
    """A policy that holds ``action`` for the first EARLY steps, then drives as ``then``."""
    step = {"k": 0}

    def act(obs, rngs):
        step["k"] += 1
        if step["k"] <= EARLY:
            return np.full(len(obs), action)
        return then(obs, rngs)

    return act


def _first_steps(config: dict, policy, seeds: list[int]) -> pd.DataFrame:
    return rollout(config, policy, seeds, "vector", batch=len(seeds)).episodes  # one batch:
    # held_then counts the policy's calls as steps


def check_episodes(df: pd.DataFrame, folder: Path) -> pd.DataFrame:
    """Every early crash of :data:`EGOS` with the three checks of the module docstring."""
    cfg = validate(OmegaConf.merge(compose("evaluate", []), OmegaConf.load(folder / CONFIG)))
    key = ["density", "mix", "radius", "seed"]
    idm = df[df.policy == "idm"].set_index(key)
    early = df[df.policy.isin(EGOS) & df.crashed.astype(bool) & (df.steps <= EARLY)]
    rows = []
    for (policy, density, mix, radius), g in early.groupby(["policy", *key[:3]], sort=True):
        config = cell_env_config(cfg, Cell(float(mix), str(density), float(radius)))
        ego = baseline(policy, config)
        seeds = [int(s) for s in g.seed]
        again = _first_steps(config, ego, seeds)
        survive = np.zeros(len(seeds), dtype=int)
        for a in range(ACTIONS):
            e = _first_steps(config, held_then(a, ego), seeds)
            survive += ~(e.crashed.astype(bool) & (e.steps <= EARLY)).to_numpy()
        for i, r in enumerate(g.itertuples()):
            other = idm.loc[(density, mix, radius, r.seed)]
            rows.append(
                {
                    "ego": policy,
                    "density": density,
                    "mix": mix,
                    "radius": radius,
                    "seed": r.seed,
                    "step": r.steps,
                    "ending": r.ending,
                    "replayed": bool(again.crashed.iloc[i]) and again.steps.iloc[i] == r.steps,
                    "idm survives": not (bool(other.crashed) and other.steps <= EARLY),
                    "actions that survive": int(survive[i]),
                }
            )
    return pd.DataFrame(rows)


def main(folder: str = "results/evaluation/baselines/paper", out: str = "") -> None:
    warnings.filterwarnings("ignore")
    folder = Path(folder)
    df = pd.read_parquet(folder / "episodes.parquet")
    df = df[df.policy.isin([*EGOS, "idm"])]
    print(rates(df).to_markdown(index=False, floatfmt=".3g"), "\n")
    checked = check_episodes(df, folder)
    if out:
        checked.to_csv(out, index=False)
    summary = checked.groupby(["ego", "density"]).agg(
        early_crashes=("seed", "size"),
        replayed=("replayed", "sum"),
        idm_survives=("idm survives", "sum"),
        some_action_survives=("actions that survive", lambda s: int((s > 0).sum())),
        lane_change_endings=("ending", lambda s: int((s == "lane_change").sum())),
        rear_end_endings=("ending", lambda s: int((s == "rear_end").sum())),
        rear_ended=("ending", lambda s: int((s == "rear_ended").sum())),
    )
    print(summary.reset_index().to_markdown(index=False))


if __name__ == "__main__":
    main(*sys.argv[1:3])
