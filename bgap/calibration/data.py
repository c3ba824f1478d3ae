"""Calibration to observed traffic: ``python -m bgap.calibrate calibrate.target=PATH``.

The paper's mode (:mod:`bgap.calibration.calibrate`) fits each class's mean CMetric score to a
number.
This mode fits bgap's two driver classes to a labelled trajectory table instead: any table
CMetric reads, with ``label`` and ``lane`` columns (labels map to the classes by
``calibrate.aggressive_prefix``: :func:`bgap.calibration.kinematics.driver_class`).

- **What is compared**: per class, the distributions of the CMetric score, the speed, the
  time headway to the leader, the longitudinal acceleration and the lane changes per
  vehicle-minute (:mod:`bgap.calibration.kinematics`). Each statistic's Wasserstein-1 distance
  between
  the simulated and the observed sample, over the observed sample's standard deviation,
  weighted by ``calibrate.weights``; the objective is their weighted mean, plus the paper
  mode's penalties for degenerate traffic (too many crashes, stalled traffic), plus (with
  ``calibrate.reference_penalty``) a penalty on every statistic the trial matches worse
  than Table I does on the same scenes: a weighted mean alone lets the search trade a
  statistic Table I already matched for a larger gain elsewhere (ours).
- **Both classes at once**: one Optuna study over both classes' searched parameters
  (``aggressive.v0``, ``conservative.v0``, ...), because CMetric scores are relative to
  the scene: one class's fit depends on how the other drives.
- **Scene noise**: every trial simulates the same seeded scenes (common random numbers:
  trials differ only in their parameters).
- **The scene from the data**: the lane count, the vehicles per km and lane
  (:func:`matched_density`) and the aggressive share of the target
  (:func:`bgap.calibration.kinematics.scene`), unless ``calibrate.scene_from_data=false``; the
  vehicle
  count stays the ``calibrate.density`` preset's and the limit highway-env's 30 m/s (the
  report shows the target's 85th-percentile speed beside it): bgap's drivers are not
  clipped to the limit, which reaches only the ego, stock drivers and the spawn speeds
  (forgotten in the warm-up), so one from the data would not change the classes' traffic.
  ``calibrate.warmup`` seconds
  are simulated before the measured ``calibrate.duration`` (data recorded at a steady state).
- **Converged** when every statistic's simulated mean lies within the noise band of the
  difference: the standard errors of the target's per-scene means and of the simulated
  scenes' (a single scene: the sample mean's, which treats its frames as independent:
  optimistic), combined in quadrature, times a Bonferroni z over the statistics compared
  (:func:`comparison`).

Outputs in the report folder: ``statistics.csv``/``.md`` (per class and statistic: target,
Table I's traffic and the calibrated traffic, means and distances), ``statistics.png``
(the distributions), ``sensitivity.csv``/``.md``/``.png`` (:func:`sensitivity`: what the
data pins down), ``convergence.png``, ``scores.json``; the preset as in the paper mode.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd

from bgap.agents.policies import rollout
from bgap.calibration.config import CalibrateAppConfig
from bgap.calibration.data_report import write_report
from bgap.calibration.kinematics import (
    ALL_STATISTICS,
    Scene,
    class_samples,
    compare,
    driver_class,
    scene,
    total_distance,
)
from bgap.cmetric.io import TrajectoryError, load_trajectories
from bgap.cmetric.score import score_trajectories
from bgap.common.presets import write_preset
from bgap.common.runs import file_digest
from bgap.common.studies import open_storage, resumable_study, run_until
from bgap.common.vocab import CLASSES
from bgap.traffic.behaviors import BehaviorConfig, DriverParams, paper_behavior
from bgap.traffic.scenario import env_config, env_preset


@dataclass
class Observed:
    """The target's statistics per class, their noise bands and the scene it implies."""

    samples: dict[str, dict[str, np.ndarray]]
    band: dict[str, dict[str, float]]
    """Two standard errors of each statistic's mean (see the module docstring)."""
    scene: Scene
    vehicles: dict[str, int]
    vehicles_density: float | None = None
    """bgap's ``env.vehicles_density`` whose scenes hold the target's vehicles per km and
    lane (:func:`matched_density`); None: the ``calibrate.density`` preset's."""


def _statistics(table: pd.DataFrame, cfg: CalibrateAppConfig, fps: float) -> dict:
    """Per class, the kinematic samples of ``table`` and its vehicles' CMetric scores."""

    c = cfg.calibrate
    samples = class_samples(table, fps=fps, aggressive_prefix=c.aggressive_prefix)
    vehicles = score_trajectories(table, cfg.cmetric, fps=fps).vehicles
    vehicles["cls"] = driver_class(vehicles.label, c.aggressive_prefix).to_numpy()
    for cls in samples:
        scores = vehicles.loc[vehicles.cls == cls, "aggressiveness"].dropna()
        samples[cls]["score"] = scores.to_numpy()
    return samples


def _bands(table: pd.DataFrame, samples: dict, cfg: CalibrateAppConfig, fps: float) -> dict:
    """Per class and statistic, two standard errors of its mean: across the table's scenes
    (their means) where it has two or more, else of the sample mean (optimistic: it treats
    a scene's frames as independent)."""
    per_scene: dict[str, dict[str, list[float]]] = {cls: {} for cls in samples}
    if table.episode.nunique() >= 2:
        for _, part in table.groupby("episode"):
            try:
                stats = _statistics(part, cfg, fps)
            except TrajectoryError:  # a scene CMetric cannot score (one vehicle, one frame)
                continue
            for cls, by_name in stats.items():
                for name, values in by_name.items():
                    if len(values) and cls in per_scene:
                        per_scene[cls].setdefault(name, []).append(float(np.mean(values)))
    band: dict[str, dict[str, float]] = {}
    for cls, by_name in samples.items():
        band[cls] = {}
        for name, values in by_name.items():
            means = per_scene[cls].get(name, [])
            if len(means) >= 2:
                band[cls][name] = 2 * float(np.std(means, ddof=1) / np.sqrt(len(means)))
            elif len(values) >= 2:
                band[cls][name] = 2 * float(np.std(values, ddof=1) / np.sqrt(len(values)))
            else:
                band[cls][name] = float("nan")
    return band


def observe(cfg: CalibrateAppConfig) -> Observed:
    """Read and check the target table (every defect is an error before any simulation),
    then measure it."""
    c = cfg.calibrate
    table = load_trajectories(c.target, fps=c.target_fps, extra=("lane",))  # any alias
    if "label" not in table:
        raise TrajectoryError(
            f"{c.target} has no 'label' column: calibration to data needs each vehicle's "
            "class (labels starting with calibrate.aggressive_prefix are aggressive)"
        )
    per_vehicle = table.drop_duplicates(["episode", "vehicle_id"])
    classes = driver_class(per_vehicle.label, c.aggressive_prefix)
    counts = {cls: int((classes == cls).sum()) for cls in CLASSES}
    few = {cls: n for cls, n in counts.items() if n < c.min_vehicles}
    if few:
        raise TrajectoryError(
            f"{c.target}: too few vehicles of class {few} (calibrate.min_vehicles="
            f"{c.min_vehicles}); both classes must be present, labelled "
            f"'{c.aggressive_prefix}...' for aggressive and anything else for conservative"
        )
    samples = _statistics(table, cfg, c.target_fps)
    band = _bands(table, samples, cfg, c.target_fps)
    found = scene(table, fps=c.target_fps, aggressive_prefix=c.aggressive_prefix)
    return Observed(samples, band, found, counts)


def simulated_scene(cfg: CalibrateAppConfig, observed: Observed) -> tuple[Any, float]:
    """The env config and the mix every trial simulates (``calibrate.warmup`` seconds
    longer than ``calibrate.duration``: the warm-up is simulated, not measured)."""
    c = cfg.calibrate
    env = replace(env_preset(c.density), duration=c.duration + c.warmup)
    mix = c.scene_mix
    if c.scene_from_data:
        env = replace(env, lanes_count=max(observed.scene.lanes, 1))
        if observed.vehicles_density is not None:
            env = replace(env, vehicles_density=observed.vehicles_density)
        mix = float(np.clip(observed.scene.aggressive_share, 0.1, 0.9))  # both classes
    return env, mix


def matched_density(cfg: CalibrateAppConfig, observed: Observed) -> float:
    """The ``vehicles_density`` at which bgap's scenes start with the target's vehicles per km
    and lane. highway-env spawns each vehicle a random gap ahead of the last, proportional
    to 1 / vehicles_density (``Vehicle.create_random``), so the density scales linearly with
    it: measured on the first frames of the calibration scenes at density 1, then scaled
    (clipped to [0.1, 10])."""
    env, mix = simulated_scene(cfg, replace(observed, vehicles_density=None))
    at_one = _first_frame_density(cfg, replace(env, vehicles_density=1.0), mix)
    return float(np.clip(observed.scene.vehicles_per_km_lane / at_one, 0.1, 10.0))


def simulate(
    cfg: CalibrateAppConfig, behavior: BehaviorConfig, observed: Observed, bands: bool = False
) -> dict:
    """Statistics of the calibration scenes under ``behavior``, and the degeneracy figures
    (with ``bands``, also the simulated statistics' noise bands, as the target's)."""
    c = cfg.calibrate
    env, mix = simulated_scene(cfg, observed)
    run = replace(cfg, env=env, behavior=behavior, mix=mix)
    seeds = range(c.scene_seed, c.scene_seed + c.episodes)
    table = rollout(env_config(run), "idle", seeds, cfg.backend, record=True).trajectories
    table = table[table.time >= c.warmup - 1e-9]  # measured after the warm-up
    final = table[table.frame == table.groupby("episode").frame.transform("max")]
    others = table[~table.is_ego]
    fps = float(env.simulation_frequency)
    samples = _statistics(table, cfg, fps)  # the ego stays in the scene; no statistic counts it
    return {
        "samples": samples,
        "band": _bands(table, samples, cfg, fps) if bands else None,
        "crashed": float(final[~final.is_ego].crashed.mean()),
        "speed": {cls: float(others.loc[others.label == cls, "speed"].mean()) for cls in CLASSES},
    }


def objective_value(
    cfg: CalibrateAppConfig, observed: Observed, sim: dict, reference: pd.Series | None = None
) -> float:
    """The weighted mean scaled distance, plus the paper mode's degeneracy penalties; with a
    ``reference`` (Table I's scaled distance per (class, statistic) on the same scenes,
    :func:`reference_distances`), ``calibrate.reference_penalty`` times the weighted mean of
    the statistics' excesses over it (a statistic Table I matches better then costs
    1 + reference_penalty times its excess in the mean's units)."""

    c = cfg.calibrate
    table = compare(observed.samples, sim["samples"], asdict(c.weights))
    value = total_distance(table)
    value = 10.0 if not np.isfinite(value) else value
    if reference is not None and c.reference_penalty > 0:  # on the mean's scale and weights
        kept = table.dropna(subset=["scaled"]).set_index(["class", "statistic"])
        excess = (kept.scaled - reference.reindex(kept.index)).clip(lower=0).fillna(0.0)
        value += c.reference_penalty * float(np.average(excess, weights=kept.weight))
    if sim["crashed"] > c.max_crashed:
        value += 1.0 + (sim["crashed"] - c.max_crashed)
    for cls in CLASSES:
        if not sim["speed"][cls] >= c.min_speed:
            value += 1.0 + (c.min_speed - np.nan_to_num(sim["speed"][cls])) / c.min_speed
    return float(value)


def reference_distances(
    cfg: CalibrateAppConfig, observed: Observed, table1: dict | None = None
) -> pd.Series | None:
    """Table I's scaled distance to the target per (class, statistic), on the scenes every
    trial simulates (None without ``calibrate.reference_penalty``); ``table1``: Table I's
    :func:`simulate` on those scenes, when already made."""
    if cfg.calibrate.reference_penalty <= 0:
        return None
    sim = table1 if table1 is not None else simulate(cfg, paper_behavior(), observed)
    return compare(observed.samples, sim["samples"]).set_index(["class", "statistic"]).scaled


def behavior_from(base: BehaviorConfig, params: dict[str, float]) -> BehaviorConfig:
    """``base`` with the ``<class>.<parameter>`` values of ``params``."""
    updates = {}
    for cls in CLASSES:
        mine = {k.split(".", 1)[1]: v for k, v in params.items() if k.startswith(f"{cls}.")}
        if mine:
            updates[cls] = DriverParams(**{**asdict(getattr(base, cls)), **mine})
    return replace(base, name="calibrated", **updates)


def study_name(cfg: CalibrateAppConfig) -> str:
    """One study per target file (its bytes) and everything that changes a trial's value."""
    c = cfg.calibrate
    keys = {
        "target": file_digest(c.target, "sha1"),
        "prefix": c.aggressive_prefix,
        "fps": c.target_fps,
        "weights": asdict(c.weights),
        "bounds": c.bounds.searched(),
        "density": c.density,
        "mix": c.scene_mix,
        "from_data": c.scene_from_data,
        "warmup": c.warmup,
        "episodes": c.episodes,
        "duration": c.duration,
        "seed": c.scene_seed,
        "limits": [c.max_crashed, c.min_speed],
        "cmetric": asdict(cfg.cmetric),
        "start": asdict(cfg.behavior),
        "backend": cfg.backend,
    }
    if c.reference_penalty > 0:  # named only when used: earlier studies keep their names
        keys["reference_penalty"] = c.reference_penalty
    digest = hashlib.sha1(json.dumps(keys, sort_keys=True, default=str).encode()).hexdigest()
    return f"{c.study}-data-{digest[:8]}"


def fit(
    cfg: CalibrateAppConfig,
    observed: Observed,
    storage,
    progress: bool = True,
    reference: pd.Series | None = None,
) -> optuna.Study:
    """Run (or continue) the study until it holds ``calibrate.trials`` completed trials
    (``reference``: :func:`reference_distances`, for the penalty)."""
    c = cfg.calibrate
    bounds = c.bounds.searched()
    start = {}  # the starting behaviour preset first, inside the bounds
    for cls in c.classes:
        preset = asdict(getattr(cfg.behavior, cls))
        for key, (lo, hi) in bounds.items():
            value = preset.get(key)
            value = (lo + hi) / 2 if value is None else value
            start[f"{cls}.{key}"] = float(min(max(value, lo), hi))
    sampler = optuna.samplers.TPESampler(seed=c.sampler_seed, n_startup_trials=10)
    study = resumable_study(storage, study_name(cfg), ["minimize"], sampler, start=start)

    def objective(trial: optuna.Trial) -> float:
        params = {
            f"{cls}.{k}": trial.suggest_float(f"{cls}.{k}", lo, hi)
            for cls in c.classes
            for k, (lo, hi) in bounds.items()
        }
        sim = simulate(cfg, behavior_from(cfg.behavior, params), observed)
        trial.set_user_attr("crashed", sim["crashed"])
        for cls in CLASSES:
            trial.set_user_attr(f"speed_{cls}", sim["speed"][cls])
        return objective_value(cfg, observed, sim, reference)

    return run_until(study, objective, c.trials, progress)


def comparison(observed: Observed, arms: dict[str, dict]) -> pd.DataFrame:
    """Per class and statistic: the target's mean and noise band (two standard errors), and
    per simulated arm (``table1``, ``calibrated``) its mean, scaled distance, the band of
    the difference of the two means and whether it lies within.

    The difference's band joins the target's and the arm's standard errors in quadrature and
    is Bonferroni-corrected over the m statistics compared: z = Phi^-1(1 - 0.05 / (2 m))
    standard errors (2.81 for m = 10), so "every statistic lies in its band" is a claim at a
    family-wise 95% (uncorrected, even the true parameters would miss one of ten statistics
    in about two runs of five)."""
    # Imported here: scipy.stats takes ~0.3 s to import; only this statistic needs it.
    from scipy.stats import norm

    m = sum(np.isfinite(b) for by_name in observed.band.values() for b in by_name.values())
    z = float(norm.ppf(1 - 0.05 / (2 * max(m, 1))))
    rows = []
    for cls, by_name in observed.samples.items():
        for name in ALL_STATISTICS:
            target = by_name.get(name, np.empty(0))
            row = {
                "class": cls,
                "statistic": name,
                "target": float(np.mean(target)) if len(target) else np.nan,
                "band": observed.band[cls].get(name, np.nan),
            }
            for arm, sim in arms.items():
                table = compare({cls: {name: target}}, sim["samples"])
                one = table[table.statistic == name]
                mean = float(one.simulated_mean.iloc[0]) if len(one) else np.nan
                own = (sim.get("band") or {}).get(cls, {}).get(name, 0.0)
                band = z * float(np.hypot(row["band"], own)) / 2  # both means are noisy
                row[f"{arm}_mean"] = mean
                row[f"{arm}_distance"] = float(one.scaled.iloc[0]) if len(one) else np.nan
                row[f"{arm}_band"] = band
                row[f"{arm}_in_band"] = bool(abs(mean - row["target"]) <= band)
            rows.append(row)
    return pd.DataFrame(rows)


def sensitivity(
    cfg: CalibrateAppConfig,
    observed: Observed,
    study: optuna.Study,
    reference: pd.Series | None = None,
) -> pd.DataFrame:
    """What the data pins down: per searched parameter, Optuna's importance (fANOVA over the
    study's trials) and a one-at-a-time sweep around the best trial
    (``calibrate.sensitivity_points`` values across its bounds, the others at their best).

    The objective's noise is measured by rerunning the best parameters on
    ``calibrate.noise_repeats`` other sets of scenes; a parameter is **identified** when its
    sweep raises the objective by more than two noise standard deviations somewhere, and its
    **plausible range** is the swept values whose objective lies within that margin of the
    best (where it is not identified, about its whole interval)."""
    c = cfg.calibrate
    best = dict(study.best_params)
    base = study.best_value  # the same scenes give the same value (common random numbers)
    repeats = []
    for k in range(1, c.noise_repeats + 1):
        other = replace(cfg, calibrate=replace(c, scene_seed=c.scene_seed + 1000 * k))
        sim = simulate(other, behavior_from(cfg.behavior, best), observed)
        repeats.append(objective_value(cfg, observed, sim, reference_distances(other, observed)))
    noise = float(np.std([base, *repeats], ddof=1)) if repeats else float("nan")
    margin = 2 * noise if np.isfinite(noise) else 0.0
    try:
        importance = optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError):  # too few or identical trials
        importance = {}
    bounds = c.bounds.searched()
    rows, curves = [], []
    for name, value in best.items():
        lo, hi = bounds[name.split(".", 1)[1]]
        grid = np.union1d(np.linspace(lo, hi, c.sensitivity_points), [value])
        values = []
        for x in grid:
            if x == value:  # the best trial itself, on the same scenes
                values.append(base)
            else:
                params = {**best, name: float(x)}
                sim = simulate(cfg, behavior_from(cfg.behavior, params), observed)
                values.append(objective_value(cfg, observed, sim, reference))
            curves.append({"parameter": name, "value": float(x), "objective": values[-1]})
        values = np.asarray(values)
        near = grid[values <= base + margin]
        rows.append(
            {
                "parameter": name,
                "best": value,
                "importance": importance.get(name, np.nan),
                "objective_best": base,
                "objective_max": float(values.max()),
                "identified": bool(values.max() > base + margin) if margin > 0 else None,
                "plausible_low": float(near.min()) if len(near) else value,
                "plausible_high": float(near.max()) if len(near) else value,
                "low": lo,
                "high": hi,
            }
        )
    table = pd.DataFrame(rows).sort_values("importance", ascending=False, na_position="last")
    table.attrs.update(noise=noise, curves=pd.DataFrame(curves))
    return table


def calibrate_to_data(
    cfg: CalibrateAppConfig,
    storage: str,
    preset: Path,
    report: Path,
    progress: bool = True,
    observed: Observed | None = None,
) -> dict[str, Any]:
    """Observe the target (unless ``observed`` already), fit both classes, write the preset
    to ``preset`` and the report into ``report`` (the Optuna study in ``storage``, a URL;
    :mod:`bgap.calibration.calibrate` names the three as for the paper's mode)."""
    storage = open_storage(storage, key="calibrate.storage")  # a bad URL: at once
    observed = observe(cfg) if observed is None else observed
    if cfg.calibrate.scene_from_data:
        observed = replace(observed, vehicles_density=matched_density(cfg, observed))
    table1 = simulate(cfg, paper_behavior(), observed, bands=True)  # the report's and the penalty's
    reference = reference_distances(cfg, observed, table1)
    study = fit(cfg, observed, storage, progress, reference)
    calibrated = behavior_from(cfg.behavior, dict(study.best_params))
    arms = {"table1": table1, "calibrated": simulate(cfg, calibrated, observed, bands=True)}
    table = comparison(observed, arms)
    missed = table[~table.calibrated_in_band & table.band.notna()]
    calibrated = replace(calibrated, name=Path(preset).stem, converged=missed.empty)
    if not missed.empty:
        listed = ", ".join(f"{r['class']} {r.statistic}" for _, r in missed.iterrows())
        warnings.warn(
            f"calibration to {cfg.calibrate.target} left {len(missed)} statistic(s) outside "
            f"the target's noise band ({listed}): the preset is marked converged: false",
            stacklevel=2,
        )
    owner = f"report: {report}"
    note = f"Written by python -m bgap.calibrate calibrate.target={cfg.calibrate.target}; {owner}"
    write_preset(calibrated, "behavior", preset, note, owner)
    points = cfg.calibrate.sensitivity_points
    sensitive = sensitivity(cfg, observed, study, reference) if points else None
    env, mix = simulated_scene(cfg, observed)
    simulated = {
        "lanes": env.lanes_count,
        "vehicles_count": env.vehicles_count,
        "vehicles_density": env.vehicles_density,
        "vehicles_per_km_lane": _first_frame_density(cfg, env, mix),
        "warmup": cfg.calibrate.warmup,
        "mix": mix,
    }
    return write_report(
        cfg.calibrate.target,
        Path(report),
        observed,
        study,
        arms,
        table,
        calibrated,
        simulated,
        sensitive,
    )


def _first_frame_density(cfg: CalibrateAppConfig, env, mix: float) -> float:
    """Vehicles per km and lane on the first frames of the calibration scenes (reported
    beside the target's)."""
    c = cfg.calibrate
    probe = replace(cfg, env=replace(env, duration=1.0), mix=mix)
    seeds = range(c.scene_seed, c.scene_seed + c.episodes)
    table = rollout(env_config(probe), "idle", seeds, cfg.backend, record=True).trajectories
    return scene(table[table.frame == 0]).vehicles_per_km_lane
