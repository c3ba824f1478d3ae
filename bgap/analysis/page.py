"""The results page (``results/README.md``): what the study found, with its tables and
figures."""

from __future__ import annotations

import json

from bgap.analysis.claims import MIN_SEEDS, ablation_table
from bgap.analysis.episodes import ALPHA, duplicates, is_replay, n_of
from bgap.analysis.stats import RULE_FLOOR, STOCK_MARGIN
from bgap.analysis.tables import (
    EARLY_STEPS,
    claims_markdown,
    departures_markdown,
    fault_markdown,
    own_markdown,
    paper_comparison,
    replay_markdown,
    rule_markdown,
    selection_markdown,
    table2,
    yardstick_markdown,
)
from bgap.analysis.yardsticks import MIN_SEEDS as YARDSTICK_SEEDS
from bgap.analysis.yardsticks import markdown as yardstick_versus
from bgap.common.vocab import SPEED_FLOOR


def readme(df, stats, table, own, sources, models, paths, yard, left_out=(), versus=None) -> str:
    ablated = ablation_table(df)
    trained = df[df.train_seed >= 0]
    seeds = trained.groupby(["arm", "density", "family"]).train_seed.nunique()
    sizes = ", ".join(f"{arm}: {int(n)}" for arm, n in seeds.groupby(level=0).max().items())
    dup = duplicates(df[df.traffic == "paper"])
    dup_text = "; ".join(f"n = {n_of(d)}: mix {m:g} repeats mix {o:g}"
                         for (d, m), o in sorted(dup.items())) or "none"  # fmt: skip
    figures = ", ".join(f"`figures/{p.name}`" for k, p in paths.items() if p.suffix == ".png")
    flagged = own[~own.beats_idle] if len(own) else own
    parts = [
        "# Results (written by `python -m bgap.figures`; do not edit)\n",
        "Source: "
        + ", ".join(f"`{s}`" for s in sources)
        + f": {len(df):,} evaluation episodes ({(df.traffic == 'stock').sum():,} of them in "
        f"stock traffic, {is_replay(df.traffic).sum():,} in replayed traffic); training seeds "
        f"per policy and arm: {sizes}. "
        f"Figures: {figures}. Per-cell numbers: `cells.csv` (with `n_seeds`, `n_episodes`); "
        f"claims: `claims.csv`; own traffic: `own_traffic.csv`.\n",
        f"Cells that repeat another cell's traffic (the same number of aggressive drivers, "
        f"so the same episodes): {dup_text}. They are shown in the per-cell tables and "
        "counted once in every average over mixes and in the claims.\n",
        *_left_out(left_out),
        "## Does each trained policy beat idle in its own training traffic?\n",
        "Own traffic: behaviour-rich on the mixes it trained on, default in highway-env's "
        "stock traffic; largest radius; fewer collisions than the idle ego at a mean speed of "
        f"at least {SPEED_FLOOR:g} x idle's, on the same episodes. The comparisons below of a "
        "policy that does not are not evidence about behaviour-rich training.\n",
        own_markdown(own) if len(own) else "(no trained policies)\n",
        (f"**{len(flagged)} do not beat idle.**\n" if len(flagged) else "All beat idle.\n"),
        "## Against the rule-based ego, per kilometre\n",
        "The yardstick a learned policy must beat: the rule-based ego (IDM + "
        "MOBIL over the meta-actions) on the same episodes. A slower policy drives fewer "
        "kilometres per episode, so safety is read per 100 km of ego travel (the ego's speed "
        "sampled each policy step x the step's duration) as well as per episode. A policy "
        f"**beats** the rule-based ego with fewer collisions per 100 km at a mean speed of at "
        f"least {RULE_FLOOR:g} x its speed; is *beaten* with no fewer and no faster; else "
        "it is *safer, slower* or *faster, less safe*. Point estimates decide; intervals in "
        "`cells.csv` (`per_100km_lo`, `per_100km_hi`) and in `figures/speed_vs_safety.png`.\n",
        rule_markdown(stats),
        "### Does a learned policy drive as well as the hand-built driver?\n",
        "The two rules, per arm that trains both policies: the behaviour-rich policy "
        "beats the rule-based ego in the paper's dense traffic (the mean over the cells above "
        "of collisions per 100 km and of speed: fewer collisions at a speed of at least "
        f"{RULE_FLOOR:g} x its speed), and the default policy keeps up with it in stock "
        f"traffic (at most {STOCK_MARGIN:g} point more episodes with a collision, at a speed "
        f"of at least {RULE_FLOOR:g} x its). An arm that meets both is a learner that drives "
        "as well as the hand-built driver; its verdict on the paper's headline claim "
        "(behaviour-rich collides less than default, from the claims below) is the one to "
        "read. Point estimates decide; 95% intervals in brackets, across training seeds "
        "(each seed's pooled value: its crashes over its kilometres in each cell, averaged "
        "over the cells); `figures/yardstick.png` draws this table.\n",
        yardstick_markdown(stats, table, yard) if len(table) else "(no claims: one family only)\n",
        "### Against every hand-built driver, paired on the same episodes\n",
        "The rule-based ego above runs highway-env's default parameters. Beside it: the same "
        "rule with IDM's and MOBIL's parameters tuned by Optuna on validation episodes of "
        "its own (`bgap.tune_rule`, seeds apart from every other search's and from the "
        "tests; `results/yardsticks/`), and IDM alone, which keeps its lane. A learned policy "
        "*beats the hand-built driver* in a density only by beating each of the three: "
        "fewer collisions per 100 km, the whole 95% interval of the difference below zero, "
        f"at a mean speed of at least {RULE_FLOOR:g} x theirs. Each yardstick plays the "
        "policy's own episodes, so the difference is paired: its interval counts the "
        "training seeds and the shared episodes (`bgap.analysis.yardsticks`; its simulated "
        f"coverage: `docs/intervals.md`). A verdict needs {YARDSTICK_SEEDS} training "
        "seeds. Pooled over the cells of the table above; `yardsticks.csv` holds every "
        "number.\n",
        yardstick_versus(versus) if versus is not None else "(not computed)\n",
        "### Collisions by fault and by time\n",
        "Beside all collisions (the paper's count, which every claim and verdict on this page "
        "uses), the same cells split by fault and by time: *at fault* counts the ego's own "
        "rear-ends and lane changes (nuPlan's convention), not being run into from behind; "
        f"*in the first {EARLY_STEPS} steps* and *after the first step* count collisions by the "
        "policy step they ended in. Episodes pooled over training seeds and cells; "
        "descriptive, without intervals.\n",
        fault_markdown(df),
        "## In observed traffic (replayed tables)\n",
        "The paper's premise is that behaviour-rich training prepares a policy for real "
        "traffic. Here every policy drives among recorded vehicles: tables of SUMO "
        "runs with bgap's fixed validation drivers (`replay_data@<table>`), the ego put in "
        "place of a recorded vehicle for at most the episode's duration; `log`: the recorded "
        "vehicles follow their log whatever the ego does (a crash may be a log vehicle "
        "running into the ego), `reactive`: one behind the ego takes over with IDM. Each "
        "model plays the tables of its own density on seeded windows. The aggressive share is "
        "the table's labels'. The claim 'behaviour-rich collides less than default in "
        "observed traffic' is tested below, in each arm's exploratory replay family.\n",
        replay_markdown(stats),
        "## The paper's claims\n",
        "a - b as the claim reads (collision percentage points, m/s or lane changes per "
        "episode). Training seeds are the independent units, and every seed of an arm plays "
        "the same episodes, so each interval counts both the spread between seeds and the "
        "draw of the shared episodes (a two-way random-effects interval, Student t with "
        "Satterthwaite's degrees of freedom; `bgap.analysis.intervals`). Two policy families "
        "are unrelated trainings on the same episodes; one model in two traffic conditions is "
        "paired by training seed; two perception radii play the same scenes, so per-scene "
        "differences are read. p-values are analytic. `docs/intervals.md` gives these "
        "intervals' coverage in simulated studies of this design, beside the two-level "
        "bootstrap's that the page printed before: they cover at least 93% at 5 and 10 seeds, "
        "except claims on the same models (paired, or on the same scenes) whose seeds' rates "
        "are strongly skewed. "
        f"A verdict needs {MIN_SEEDS} training seeds per side. The main arm's claims in "
        "bgap's traffic are the confirmatory family (the claims of `bgap/analysis/paper.py`; "
        "named after the committed evaluation ran, so binding from the next one); every other "
        "arm, and every claim in observed traffic, is an exploratory family of its own. "
        "Holm's correction runs within each family "
        f"({_families(table)}), so adding an arm changes no other arm's verdict; the verdict "
        f"follows from the corrected p-value (alpha {ALPHA:g}) and the corrected interval is "
        "the claim's interval at the level Holm's step tests it at.\n",
        claims_markdown(table) if len(table) else "(no claims: one family only)\n",
        "## Training traffic: one mix or the mixture (ablation)\n",
        "Behaviour-rich trained at one mix minus behaviour-rich trained on the mixture of the "
        "paper's mixes (main arm), collision percentage points, largest radius; unrelated "
        "trainings on the same episodes (the claims' interval), exploratory (no correction). "
        "Figure: `figures/ablation.png`.\n",
        (ablated.to_markdown(index=False, floatfmt=".2f") if len(ablated) else "(no ablation arms)")
        + "\n",
        "## Collisions and speed beside the paper's bars (main arm)\n",
        paper_comparison(stats),
        "## Table II\n",
        "Our rates for every policy in Table II's cell; the paper reports no interval and no "
        "baseline in that cell, so its 3.00% should be read against idle's and default's "
        "rates there.\n",
        table2(stats),
        "## Where the arms differ\n",
        departures_markdown(models),
        "## Checkpoints the trainings kept\n",
        f"Each training validates {_validation(models)} of its own traffic and keeps the "
        "validation with the highest mean return under its own reward "
        "(`best_model.zip`, SB3's EvalCallback rule; ours: the paper keeps none); the test "
        "episodes play that checkpoint.\n",
        selection_markdown(models),
    ]
    return "\n".join(parts)


def _families(table) -> str:
    sizes = table.groupby("family").size()
    return "; ".join(f"{name}: {n} claims" for name, n in sizes.items())


def _validation(models) -> str:
    """How the trainings validated, from their stored settings (every schedule in use)."""
    counts: dict[tuple, int] = {}
    for text in models.drop_duplicates("policy").settings.dropna():
        p = json.loads(text).get("profile", {})
        key = (p.get("eval_every_episodes"), p.get("eval_during_training"))
        counts[key] = counts.get(key, 0) + 1
    parts = [f"every {every} episodes on {n} episodes ({k} policies)"
             for (every, n), k in sorted(counts.items(), key=lambda kv: -kv[1])]  # fmt: skip
    return "; ".join(parts) or "(no stored settings)"


def _left_out(mismatches) -> list[str]:
    """The page's paragraph on cells left out of every comparison (none: nothing)."""
    if not mismatches:
        return []
    by_stage: dict[str, list] = {}
    for m in mismatches:
        by_stage.setdefault(f"evaluate@{m.arm}", []).append(m)
    lines = [f"- `{stage}`: {len(ms)} traffic cells ({', '.join(m.traffic for m in ms)}); "
             f"{ms[0].reason}." for stage, ms in by_stage.items()]  # fmt: skip
    return [
        "## Cells left out\n",
        "These cells played other traffic than the baselines, so they are compared with "
        "nothing on this page (found from the episodes themselves: `bgap/analysis/inputs.py`). "
        "Rerun the stage to bring them back.\n",
        "\n".join(lines) + "\n",
    ]
