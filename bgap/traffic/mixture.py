"""The generalisation study's training traffic: each episode's traffic drawn from a mixture
of sources, densities, aggressive shares and driver parameters
(``docs/notes/2026-12-07-generalisation-plan.md``, where each default's reason is given).

    cfg = MixtureConfig()
    groups = vehicle_groups(cfg, n_envs=100)     # [(5, 20), (10, 20), ...]: envs per count
    episode = draw(cfg, np.random.default_rng(seed), vehicles=20)

The vector backend holds one vehicle count per batch of environments, so the count is drawn
per environment group (:func:`vehicle_groups`: the environments shared among the counts as
evenly as they divide), and everything else per episode (:func:`draw`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bgap.common.errors import check

SOURCES = ("bgap", "stock", "replay")
"""Where an episode's traffic comes from: bgap's driver classes, highway-env's stock
traffic, or a training scene of a replayed table, reactive."""


@dataclass
class MixtureConfig:
    """The mixture's weights and ranges (defaults: the plan's table)."""

    sources: dict[str, float] = field(
        default_factory=lambda: {"bgap": 0.5, "stock": 0.2, "replay": 0.3}
    )
    """Each source's weight (normalised; :data:`SOURCES`)."""
    vehicles: list[int] = field(default_factory=lambda: [5, 10, 20, 30, 40])
    """Vehicle counts, one environment group each."""
    mix: tuple[float, float] = (0.0, 1.0)
    """The aggressive share's range, drawn uniformly (bgap's source)."""
    classes: list[str] = field(default_factory=lambda: ["paper", "calibrated", "sumo_calibrated"])
    """Behaviour presets the driver classes come from, equally often (bgap's source)."""
    scale: tuple[float, float] = (0.8, 1.2)
    """Each vehicle's IDM and MOBIL parameters are its class's times a factor drawn
    uniformly in this range (bgap's source)."""
    tables: list[str] = field(default_factory=list)
    """Replay tables whose training scenes the replay source plays, reactive
    (:mod:`bgap.traffic.scenes` holds a third of each table's scenes out for testing)."""

    def __post_init__(self) -> None:
        weights = list(self.sources.values())
        check(
            set(self.sources) <= set(SOURCES) and all(w >= 0 for w in weights) and sum(weights) > 0,
            "mixture.sources",
            self.sources,
            f"weights >= 0, not all 0, of {SOURCES}",
        )
        check(
            bool(self.vehicles) and all(v >= 1 for v in self.vehicles),
            "mixture.vehicles",
            self.vehicles,
            "positive vehicle counts",
        )
        for key, (lo, hi), floor in (("mix", self.mix, 0.0), ("scale", self.scale, 1e-9)):
            ok = floor <= lo <= hi and (key != "mix" or hi <= 1.0)
            check(ok, f"mixture.{key}", (lo, hi), "an ordered range (mix within [0, 1])")
        check(bool(self.classes), "mixture.classes", self.classes, "at least one preset")


@dataclass(frozen=True)
class EpisodeTraffic:
    """One episode's draw: its source; for bgap's source its aggressive share, behaviour
    preset and per-vehicle parameter factors (NaN and empty otherwise)."""

    source: str
    mix: float = float("nan")
    behavior: str = ""
    scale: tuple[float, ...] = ()


def vehicle_groups(cfg: MixtureConfig, n_envs: int) -> list[tuple[int, int]]:
    """(vehicle count, environments) per group: ``n_envs`` shared among the counts, the
    first ``n_envs % len(counts)`` counts taking one more."""
    k = len(cfg.vehicles)
    check(n_envs >= k, "n_envs", n_envs, f"at least one environment per vehicle count ({k})")
    return [(v, n_envs // k + (i < n_envs % k)) for i, v in enumerate(cfg.vehicles)]


def draw(cfg: MixtureConfig, rng: np.random.Generator, vehicles: int) -> EpisodeTraffic:
    """One episode's traffic among ``vehicles`` vehicles, from the episode's stream ``rng``."""
    names = list(cfg.sources)
    weights = np.array([cfg.sources[n] for n in names], dtype=float)
    source = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    if source != "bgap":
        return EpisodeTraffic(source)
    return EpisodeTraffic(
        source,
        mix=float(rng.uniform(*cfg.mix)),
        behavior=cfg.classes[int(rng.integers(len(cfg.classes)))],
        scale=tuple(float(x) for x in rng.uniform(*cfg.scale, size=vehicles)),
    )
