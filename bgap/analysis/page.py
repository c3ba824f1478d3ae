"""The results page (``results/README.md``): what the study found, with its tables and
figures; its prose is the Markdown template ``page.md`` beside this module."""

from __future__ import annotations

import json
from pathlib import Path

from bgap.analysis.aggregates import markdown as aggregate_markdown
from bgap.analysis.claims import MIN_SEEDS, ablation_table
from bgap.analysis.crashes import EARLY_STEPS, fault_markdown
from bgap.analysis.episodes import ALPHA, duplicates, is_replay, n_of
from bgap.analysis.stats import RULE_FLOOR, STOCK_MARGIN
from bgap.analysis.tables import (
    claims_markdown,
    departures_markdown,
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

TEMPLATE = Path(__file__).with_name("page.md")
"""The page's prose, in Markdown, with the ``{name}`` fields :func:`readme` fills in (numbers
with their format: ``{episodes:,}``)."""


NO_CLAIMS = "(no claims: one family only)\n"


def readme(
    df, stats, table, own, sources, models, paths, yard, left_out=(), versus=None, summary=None
) -> str:
    """The page: :data:`TEMPLATE` with the study's numbers and tables filled in."""
    fields = {
        **_source(df, sources, paths),
        "left_out": "".join(part + "\n" for part in _left_out(left_out)),
        "own": own_markdown(own) if len(own) else "(no trained policies)\n",
        "beats_idle": _beats_idle(own),
        "rule": rule_markdown(stats),
        "yardstick": (
            yardstick_markdown(stats, table, yard)
            if len(table)
            else "(no claims: one family only)\n"
        ),
        "versus": yardstick_versus(versus) if versus is not None else "(not computed)\n",
        "aggregates": aggregate_markdown(summary) if summary is not None else "(not computed)\n",
        "faults": fault_markdown(df),
        "replay": replay_markdown(stats),
        "families": _families(table),
        "claims": claims_markdown(table) if len(table) else NO_CLAIMS,
        "ablation": _ablation(df),
        "paper": paper_comparison(stats),
        "table2": table2(stats),
        "departures": departures_markdown(models),
        "validation": _validation(models),
        "selection": selection_markdown(models),
        "speed_floor": SPEED_FLOOR,
        "rule_floor": RULE_FLOOR,
        "stock_margin": STOCK_MARGIN,
        "yardstick_seeds": YARDSTICK_SEEDS,
        "early_steps": EARLY_STEPS,
        "min_seeds": MIN_SEEDS,
        "alpha": ALPHA,
    }
    return TEMPLATE.read_text().format_map(fields)


def _source(df, sources, paths) -> dict[str, object]:
    """The page's opening: what it was computed from."""
    trained = df[df.train_seed >= 0]
    seeds = trained.groupby(["arm", "density", "family"]).train_seed.nunique()
    dup = duplicates(df[df.traffic == "paper"])
    return {
        "sources": ", ".join(f"`{s}`" for s in sources),
        "episodes": len(df),
        "stock_episodes": (df.traffic == "stock").sum(),
        "replay_episodes": is_replay(df.traffic).sum(),
        "sizes": ", ".join(f"{arm}: {int(n)}" for arm, n in seeds.groupby(level=0).max().items()),
        "figures": ", ".join(f"`figures/{p.name}`" for p in paths.values() if p.suffix == ".png"),
        "duplicates": "; ".join(
            f"n = {n_of(d)}: mix {m:g} repeats mix {o:g}" for (d, m), o in sorted(dup.items())
        )
        or "none",
    }


def _beats_idle(own) -> str:
    flagged = own[~own.beats_idle] if len(own) else own
    return f"**{len(flagged)} do not beat idle.**\n" if len(flagged) else "All beat idle.\n"


def _ablation(df) -> str:
    ablated = ablation_table(df)
    if not len(ablated):
        return "(no ablation arms)\n"
    return ablated.to_markdown(index=False, floatfmt=".2f") + "\n"


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
    parts = [
        f"every {every} episodes on {n} episodes ({k} policies)"
        for (every, n), k in sorted(counts.items(), key=lambda kv: -kv[1])
    ]
    return "; ".join(parts) or "(no stored settings)"


def _left_out(mismatches) -> list[str]:
    """The page's paragraph on cells left out of every comparison (none: nothing)."""
    if not mismatches:
        return []
    by_stage: dict[str, list] = {}
    for m in mismatches:
        by_stage.setdefault(f"evaluate@{m.arm}", []).append(m)
    lines = [
        f"- `{stage}`: {len(ms)} traffic cells ({', '.join(m.traffic for m in ms)}); "
        f"{ms[0].reason}."
        for stage, ms in by_stage.items()
    ]
    return [
        "## Cells left out\n",
        "These cells played other traffic than the baselines, so they are compared with "
        "nothing on this page (found from the episodes themselves: `bgap/analysis/inputs.py`). "
        "Rerun the stage to bring them back.\n",
        "\n".join(lines) + "\n",
    ]
