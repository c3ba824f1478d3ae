"""Optuna sweeps: end to end, resumable, shared by workers on a real PostgreSQL server."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
import sqlalchemy

from bgap.common.config import validate
from bgap.common.errors import ConfigError
from bgap.experiments.sweep import load_space, sweep, write_outputs
from bgap.experiments.train import train as _train  # noqa: F401  (imported early: workers fork cleanly)
from tests.configs import compose

TINY = ["profile=tiny", "sweep_eval_episodes=4"]


def _cfg(tmp_path, *overrides: str):
    return validate(
        compose("sweep", [*TINY, f"root={tmp_path}", f"preset={tmp_path}/tuned.yaml", *overrides])
    )


def test_multi_objective_sweep_writes_pareto_front_and_preset(tmp_path):
    cfg = _cfg(tmp_path, "trials=3")
    study = sweep(cfg, progress=False)
    assert len(study.trials) == 3 and len(study.directions) == 2
    paths = write_outputs(study, cfg)
    assert paths["plot"].read_bytes()[:4] == b"\x89PNG"
    front = paths["pareto"].read_text().splitlines()
    assert len(front) - 1 == len(study.best_trials) >= 1
    from bgap.common.presets import load_preset
    from bgap.experiments.sweep import chosen_trial
    from bgap.traffic.scenario import RewardConfig

    reward = load_preset(RewardConfig, tmp_path / "tuned.yaml")  # must fit the reward schema
    chosen = chosen_trial(study, cfg)
    assert chosen.number in {t.number for t in study.best_trials}
    assert reward.name == "tuned"
    for key, value in chosen.params.items():
        assert getattr(reward, key.split(".")[1]) == pytest.approx(value)
    for t in study.trials:  # every trial kept its run folder and resolved config
        assert (Path(t.user_attrs["run_dir"]) / "config.yaml").exists()


def test_resumed_sweep_continues_its_trial_count(tmp_path):
    from bgap.common.presets import load_preset
    from bgap.traffic.scenario import RewardConfig

    first = sweep(_cfg(tmp_path, "trials=2", "mode=single"), progress=False)
    numbers = [t.number for t in first.trials]
    # the same study read as a sweep of 4 trials stopped after 2: its preset says so
    with pytest.warns(UserWarning, match="holds 2 of its 4 trials"):
        write_outputs(first, _cfg(tmp_path, "trials=4", "mode=single"))
    assert not load_preset(RewardConfig, tmp_path / "tuned.yaml").converged
    with pytest.raises(ConfigError, match="sweep stopped before its trials were done"):
        validate(compose("train", ["reward.converged=false"]))
    again = sweep(_cfg(tmp_path, "trials=4", "mode=single"), progress=False)
    assert numbers == [0, 1] and [t.number for t in again.trials] == [0, 1, 2, 3]
    write_outputs(again, _cfg(tmp_path, "trials=4", "mode=single"))
    assert load_preset(RewardConfig, tmp_path / "tuned.yaml").converged


def test_a_new_machine_continues_the_sweep_from_its_trial_log(tmp_path, capsys):
    """``trial_log=``: a fresh root (its database lost) takes the logged trials and plays
    only the ones still missing; a root that holds the study ignores the log."""
    from bgap.experiments import trial_log

    lost = tmp_path / "lost"
    first = sweep(_cfg(lost, "trials=2", "mode=single", "study=s"), progress=False)
    trial_log.save(f"sqlite:///{lost}/sweeps/optuna.db", "s", tmp_path / "s.json")
    new = tmp_path / "new"
    cfg = _cfg(new, "trials=3", "mode=single", "study=s", f"trial_log={tmp_path}/s.json")
    again = sweep(cfg, progress=False)
    assert "restored 2 trials of s" in capsys.readouterr().out
    assert [t.params for t in again.trials[:2]] == [t.params for t in first.trials]
    assert [t.number for t in again.trials] == [0, 1, 2]  # one trial played, not three
    assert sorted(p.name for p in (new / "sweeps" / "s").iterdir()) == ["trial-0002"]
    # the database is there now: the log (two trials) is not restored over its three
    assert len(sweep(cfg, progress=False).trials) == 3
    assert "restored" not in capsys.readouterr().out


def test_sweep_of_the_default_policy_trains_and_scores_it_in_stock_traffic(tmp_path):
    """``policy=default`` reaches every trial's training: stock traffic, and the trial's idle
    figures are idle's on the stock validation episodes (idle crashes far more there than
    in the paper's traffic, so the two cannot be confused)."""
    import yaml

    from bgap.agents.policies import baseline
    from bgap.experiments.validation import validation_rates

    cfg = _cfg(tmp_path, "trials=1", "mode=single", "env=dense", "policy=default")
    study = sweep(cfg, progress=False)
    trial = study.trials[0]
    run = yaml.safe_load((Path(trial.user_attrs["run_dir"]) / "config.yaml").read_text())
    assert run["policy"] == "default" and run["behavior"]["name"] == "stock"
    # validation_rates swaps in the training traffic of cfg.policy itself (train.training_config)
    crash, speed = validation_rates(baseline("idle"), cfg, cfg.sweep_eval_episodes)
    assert trial.user_attrs["idle_collision_pct"] == crash
    assert trial.user_attrs["idle_avg_speed"] == pytest.approx(speed)


def test_bad_search_spaces_fail_before_training(tmp_path, monkeypatch):
    import bgap.experiments.sweep as sw

    with pytest.raises(ConfigError, match="no search space"):
        load_space("nonexistent")
    bad = tmp_path / "sweeps"
    bad.mkdir()
    (bad / "typo.yaml").write_text("params:\n  reward.colision: {low: -2, high: -1}\n")
    (bad / "inverted.yaml").write_text("params:\n  reward.collision: {low: -1, high: -2}\n")
    monkeypatch.setattr(sw, "SWEEPS_DIR", bad)
    with pytest.raises(ConfigError, match="reward.colision"):
        load_space("typo")
    with pytest.raises(ConfigError, match="low < high"):
        load_space("inverted")


# ---------------------------------------------------------------- PostgreSQL workers
def _worker(tmp_path: Path, url: str, trials: int, study: str) -> subprocess.Popen:
    cmd = [
        sys.executable,
        "-m",
        "bgap.sweep",
        *TINY,
        f"trials={trials}",
        "mode=single",
        f"storage={url}",
        f"study={study}",
        f"root={tmp_path}",
        f"preset={tmp_path}/tuned.yaml",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.slow  # ~40 s; .ci/run's cluster tests run sweep workers on PostgreSQL
def test_two_workers_share_one_postgres_study(tmp_path, postgres):
    workers = [_worker(tmp_path, postgres, 4, "shared") for _ in range(2)]
    for w in workers:
        out, _ = w.communicate(timeout=600)
        assert w.returncode == 0, out[-2000:]
    study = optuna.load_study(study_name="shared", storage=postgres)
    finished = [t for t in study.trials if t.state.is_finished()]
    # MaxTrialsCallback stops both workers at 4; one in flight may finish as a 5th.
    assert 4 <= len(finished) <= 5
    runs = [t.user_attrs["run_dir"] for t in study.trials]
    assert len(set(runs)) == len(runs)  # no trial number (run folder) done twice


@pytest.mark.slow  # ~12 s; .ci/run's cluster tests kill a sweep worker on PostgreSQL too
def test_a_killed_workers_trial_does_not_block_the_study(tmp_path, postgres, monkeypatch):
    from optuna.trial import TrialState

    w = _worker(tmp_path, postgres, 3, "killed")
    storage = optuna.storages.RDBStorage(postgres)
    engine = sqlalchemy.create_engine(postgres)
    beating = sqlalchemy.text(  # running trials whose heartbeat thread has recorded once
        "SELECT count(*) FROM trials t JOIN trial_heartbeats h ON h.trial_id = t.trial_id"
        " WHERE t.state = 'RUNNING'"
    )
    deadline = time.time() + 120
    # Wait for its first trial to start *and record a heartbeat*, then kill it. Optuna
    # never fails a running trial that has no heartbeat yet (RDBStorage._get_stale_trial_ids
    # skips it), and the heartbeat thread starts a moment after the trial turns RUNNING:
    # killing in that moment left the trial running for good (a flaky CI run).
    while time.time() < deadline:
        try:
            study = optuna.load_study(study_name="killed", storage=storage)
            with engine.connect() as db:
                if db.execute(beating).scalar():
                    break
        except (KeyError, sqlalchemy.exc.ProgrammingError):  # no study / tables yet
            pass
        time.sleep(0.5)
    engine.dispose()
    study = optuna.load_study(study_name="killed", storage=storage)
    w.send_signal(signal.SIGKILL)
    w.wait()
    stale = [t.number for t in study.trials if t.state == TrialState.RUNNING]
    assert stale
    # A new worker, after the heartbeat grace period, fails the stale trial and finishes.
    import bgap.common.studies as studies
    from bgap.experiments.sweep import sweep as run_sweep

    monkeypatch.setattr(studies, "HEARTBEAT", (1, 2))
    time.sleep(3)
    study = run_sweep(
        _cfg(tmp_path, "trials=3", "mode=single", f"storage={postgres}", "study=killed"),
        progress=False,
    )
    states = {t.number: t.state for t in study.trials}
    assert all(states[n] == TrialState.FAIL for n in stale)
    assert sum(s == TrialState.COMPLETE or s == TrialState.PRUNED for s in states.values()) >= 3
