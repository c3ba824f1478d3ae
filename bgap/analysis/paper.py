"""The paper's numbers (its bars and Table II, FACTS.md) and its claims, as comparisons of
two selections of episodes."""

from __future__ import annotations

from dataclasses import dataclass

# The paper's bars (FACTS.md): crashes per 100 episodes, at 0% / 50% / 100% aggressive.
PAPER_CRASHES = {
    ("dense", "default"): {0.0: 65, 0.5: 70, 1.0: 30},
    ("dense", "behavior_rich"): {0.0: 27, 0.5: 36, 1.0: 4},
    ("sparse", "default"): {0.0: 21, 0.5: 31, 1.0: 11},
    ("sparse", "behavior_rich"): {0.0: 5, 0.5: 14, 1.0: 3},
}
PAPER_SPEED = {
    ("dense", "behavior_rich"): {0.0: 17.8, 0.5: 20.1, 1.0: 26.0},
    ("dense", "default"): {0.0: 18.6, 0.5: 18.7, 1.0: 19.1},
}
PAPER_LANE_CHANGES = {("dense", "behavior_rich"): {0.0: 10.6, 0.5: 9.5, 1.0: 3.75}}
TABLE_II = {"DDPG": 10.13, "PS-DDPG": 11.40, "B-GAP (paper)": 3.00}


# ---------------------------------------------------------------------- claims
@dataclass(frozen=True)
class Claim:
    """One of the paper's claims as a comparison of two selections of episodes."""

    text: str
    figure: str
    metric: str
    a: dict
    b: dict | None
    expect: int
    """+1: the paper says a > b; -1: a < b."""
    design: str
    """``unpaired`` (different trainings), ``model`` (one model, two conditions), ``scene``
    (one model, the same scenes: per-episode differences) or ``value`` (a against a number)."""
    paper: str
    null: float = 0.0
    densities: tuple[str, ...] = ("sparse", "dense")


HEADLINE = "behaviour-rich collides less than default (all mixes)"
"""The paper's headline claim, as the claims table names it."""


def _claims_for(radii: list[float], mixes: list[float]) -> list[Claim]:
    # The claims are a table, one Claim per row with its fields in the order the paper
    # states them (text, figure, metric, the two sides, direction, pairing, the paper's
    # numbers): the formatter is kept off these rows (fmt: skip), which it would spread
    # over ten lines each.
    r = max(radii)
    mixed = [m for m in mixes if 0.0 < m < 1.0]
    out = [
        Claim(HEADLINE, "Fig. 4", "collision_pct",
              {"family": "behavior_rich", "radius": r}, {"family": "default", "radius": r},
              -1, "unpaired", "n=40: 27/36/4 vs 65/70/30; n=5: 5/14/3 vs 21/31/11"),
        Claim("behaviour-rich collides less at 0% than in mixed traffic", "Fig. 4",
              "collision_pct", {"family": "behavior_rich", "radius": r, "mix": [0.0]},
              {"family": "behavior_rich", "radius": r, "mix": mixed}, -1, "model",
              "n=40: 27 vs 36; n=5: 5 vs 14"),
        Claim("behaviour-rich collides less at 100% than in mixed traffic", "Fig. 4",
              "collision_pct", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": mixed}, -1, "model",
              "n=40: 4 vs 36; n=5: 3 vs 14"),
        Claim("default collides less at 100% than at 50% aggressive", "Fig. 4", "collision_pct",
              {"family": "default", "radius": r, "mix": [1.0]},
              {"family": "default", "radius": r, "mix": [0.5]}, -1, "model",
              "n=40: 30 vs 70; n=5: 11 vs 31"),
    ]  # fmt: skip
    for small in sorted(radii)[:-1]:
        out.append(
            Claim(
                f"behaviour-rich collides more with a {small:g} m than a {r:g} m perception radius",
                "Fig. 6",
                "collision_pct",
                {"family": "behavior_rich", "radius": small},
                {"family": "behavior_rich", "radius": r},
                +1,
                "scene",
                "more collisions at smaller radii (Fig. 6)",
            )  # fmt: skip
        )
    out += [
        Claim("behaviour-rich drives faster at 100% than at 0% aggressive", "Fig. 4 (speed)",
              "avg_speed", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": [0.0]}, +1, "model",
              "26.0 vs 17.8 m/s", densities=("dense",)),
        Claim("behaviour-rich drives faster than default at 100% aggressive", "Fig. 4 (speed)",
              "avg_speed", {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "default", "radius": r, "mix": [1.0]}, +1, "unpaired",
              "26.0 vs ~19.1 m/s", densities=("dense",)),
        Claim("behaviour-rich changes lanes less at 100% than at 0% aggressive",
              "Fig. 4 (lane changes)", "lane_changes",
              {"family": "behavior_rich", "radius": r, "mix": [1.0]},
              {"family": "behavior_rich", "radius": r, "mix": [0.0]}, -1, "model",
              "3.75 vs 10.6 per episode", densities=("dense",)),
        Claim("behaviour-rich collides in fewer than DDPG's 10.13% at 100% aggressive",
              "Table II", "collision_pct", {"family": "behavior_rich", "radius": r,
              "mix": [1.0]}, None, -1, "value", "3.00% (DDPG 10.13%, PS-DDPG 11.40%)",
              null=TABLE_II["DDPG"], densities=("sparse",)),
    ]  # fmt: skip
    return out


CLAIMS = _claims_for
"""The claims table's rows (per arm that trains both families, per density)."""


def replay_claim(traffic: str) -> Claim:
    """The paper's premise read in observed traffic (not in the paper): a replayed
    table (``traffic`` = ``replay/<table>/<mode>``), each family's models of the table's
    density on the same seeded windows; different trainings, so unpaired."""
    table, mode = traffic.split("/")[1:3]
    return Claim(f"behaviour-rich collides less than default in observed traffic ({table}, "
                 f"{mode})", "replay", "collision_pct", {"family": "behavior_rich"},
                 {"family": "default"}, -1, "unpaired", "not tested (its premise)")  # fmt: skip
