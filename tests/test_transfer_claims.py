"""The generalisation study's transfer claims (bgap.analysis.claims.transfer_claims): one
claim per replayed table in reactive mode, the hand-computed difference, Holm within their
own family, and log-mode or simulated cells left out."""

from __future__ import annotations

import pandas as pd
import pytest

from bgap.analysis.claims import TRANSFER, claims, transfer_claims

TABLES = {"replay/sumo-idm-dense/reactive": "dense", "replay/sumo-krauss-sparse/reactive": "sparse",
          "replay/sumo-idm-dense/log": "dense", "paper": "dense"}  # fmt: skip


def _episodes(arm: str, every: int, seeds=range(5), episodes=40) -> list[dict]:
    """Seed s crashes in episode e when (s + e) is a multiple of ``every``: exactly
    1/every of each seed's episodes in every cell."""
    return [
        {
            "arm": arm,
            "family": "behavior_rich",
            "train_seed": s,
            "traffic": traffic,
            "density": density,
            "mix": 0.3,
            "radius": 180.0,
            "seed": 100000 + e,
            "crashed": (s + e) % every == 0,
            "collision_pct": 100.0 * ((s + e) % every == 0),
            "avg_speed": 25.0,
            "lane_changes": 1,
            "distance": 1000.0,
        }  # fmt: skip
        for traffic, density in TABLES.items()
        for s in seeds
        for e in range(episodes)
    ]


def test_mixture_against_stock_per_reactive_table_with_the_hand_computed_difference():
    """5% against 25% of episodes in each reactive table: -20 points, the claim holds in
    both, in the transfer family only; the log-mode and simulated cells make no claim."""
    df = pd.DataFrame(_episodes("gen-pure", 20) + _episodes("gen-stock", 4))
    table = transfer_claims(df, {"arm": "gen-pure"}, {"arm": "gen-stock"})
    assert len(table) == 2 and set(table.family) == {TRANSFER}
    assert all("reactive" in c for c in table.claim)
    assert table.difference.tolist() == pytest.approx([-20.0, -20.0])
    assert table.value_a.tolist() == pytest.approx([5.0, 5.0])
    assert (table.lo <= table.difference).all() and (table.difference <= table.hi).all()
    assert set(table.verdict) == {"holds"}


def test_equal_arms_do_not_hold_and_the_study_claims_are_untouched():
    """The same crash pattern for both arms: a zero difference, no verdict either way; the
    study's own claims table has no transfer row."""
    df = pd.DataFrame(_episodes("gen-pure", 8) + _episodes("gen-stock", 8))
    table = transfer_claims(df, {"arm": "gen-pure"}, {"arm": "gen-stock"})
    assert table.difference.tolist() == pytest.approx([0.0, 0.0])
    assert not set(table.verdict) & {"holds", "contradicted"}
    study = claims(df)
    assert study.empty or TRANSFER not in set(study.family)
