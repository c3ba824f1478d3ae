"""A search's finished trials saved to a file git keeps, and restored into a fresh database
(bgap.experiments.trial_log, `python -m bgap.pipeline trials save|restore`): what the study
held comes back, and the search continues from there instead of starting over."""

from __future__ import annotations

import optuna
import pytest
from optuna.trial import TrialState

from bgap.commands.pipeline import main
from bgap.common.errors import ConfigError
from bgap.common.studies import run_until
from bgap.experiments import trial_log


def _objective(trial: optuna.Trial) -> float:
    x = trial.suggest_float("x", -3.0, 3.0)
    n = trial.suggest_int("n", 1, 8, log=True)
    kind = trial.suggest_categorical("kind", ["dqn", "qrdqn", None])
    trial.set_user_attr("run_dir", f"outputs/trial-{trial.number:04d}")
    for step in range(3):
        trial.report(x * x + step, step)
    if trial.number % 3 == 2:
        raise optuna.TrialPruned
    return x * x + n + (kind is None)


def _searched(tmp_path, trials: int = 7) -> str:
    storage = f"sqlite:///{tmp_path / 'lost.db'}"
    study = optuna.create_study(
        study_name="learner-dqn", storage=storage, sampler=optuna.samplers.TPESampler(seed=3)
    )
    study.set_user_attr("objective", "collisions against the rule-based ego")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study.optimize(_objective, n_trials=trials)
    return storage


def _view(study: optuna.Study) -> list[tuple]:
    return [
        (t.number, t.state, t.params, t.values, t.user_attrs, t.intermediate_values,
         t.datetime_start, t.datetime_complete)
        for t in study.trials
    ]  # fmt: skip


def test_a_restored_study_holds_the_lost_ones_trials_and_continues_after_them(tmp_path):
    storage = _searched(tmp_path)
    lost = optuna.load_study(study_name="learner-dqn", storage=storage)
    assert {t.state for t in lost.trials} == {TrialState.COMPLETE, TrialState.PRUNED}
    assert trial_log.save(storage, "learner-dqn", tmp_path / "log.json") == 7

    fresh = f"sqlite:///{tmp_path / 'fresh.db'}"
    assert trial_log.restore(fresh, tmp_path / "log.json") == 7
    back = optuna.load_study(study_name="learner-dqn", storage=fresh)
    assert _view(back) == _view(lost)
    assert back.best_params == lost.best_params and back.best_value == lost.best_value
    assert back.user_attrs == lost.user_attrs
    assert back.trials[0].distributions == lost.trials[0].distributions
    # the times came back with the trials: the search's wall time outlives its database
    ran = sum((t.datetime_complete - t.datetime_start).total_seconds() for t in lost.trials)
    hours, timed = trial_log.trial_hours(tmp_path / "log.json")
    assert timed == 7 and hours == pytest.approx(ran / 3600) and ran > 0

    # the search's own loop counts what came back (5 complete): asked for 8, it plays 3
    # trials more, numbered after the restored ones, not 8 from the start
    complete = len(back.get_trials(states=(TrialState.COMPLETE,)))
    run_until(back, _objective, complete + 3, progress=False)
    assert [t.number for t in back.trials] == list(range(10))


def test_a_running_trial_is_not_kept(tmp_path):
    storage = _searched(tmp_path, trials=2)
    study = optuna.load_study(study_name="learner-dqn", storage=storage)
    study.ask()  # a trial still running when the log is saved
    assert trial_log.save(storage, "learner-dqn", tmp_path / "log.json") == 2


def test_a_log_is_restored_on_a_new_machine_whose_root_is_not_made_yet(tmp_path, monkeypatch):
    """The documented command, from a fresh clone: storage=outputs/.../optuna.db, whose
    folders do not exist yet."""
    storage = _searched(tmp_path, trials=2)
    trial_log.save(storage, "learner-dqn", tmp_path / "log.json")
    monkeypatch.chdir(tmp_path)
    db = "outputs/pipeline/sweeps/optuna.db"
    main(["trials=restore", "log=log.json", f"storage={db}"])
    restored = optuna.load_study(study_name="learner-dqn", storage=f"sqlite:///{tmp_path / db}")
    assert len(restored.trials) == 2


def test_a_study_that_holds_trials_is_not_restored_into(tmp_path):
    storage = _searched(tmp_path, trials=2)
    trial_log.save(storage, "learner-dqn", tmp_path / "log.json")
    with pytest.raises(ConfigError, match="already holds 2 trials"):
        trial_log.restore(storage, tmp_path / "log.json")
    assert len(optuna.load_study(study_name="learner-dqn", storage=storage).trials) == 2


def test_a_log_fills_only_a_database_that_lacks_its_study(tmp_path):
    """``restore_if_missing``, what ``trial_log=`` of a search calls before it opens its
    study: a new database gets the log; one holding the study, an absent log (a first run)
    and another study's log change nothing, the last with one line."""
    storage = _searched(tmp_path, trials=3)
    trial_log.save(storage, "learner-dqn", tmp_path / "log.json")
    fresh = f"sqlite:///{tmp_path / 'new' / 'optuna.db'}"  # its folder not made yet
    assert trial_log.restore_if_missing(fresh, "learner-dqn", tmp_path / "log.json") == 3
    assert trial_log.restore_if_missing(fresh, "learner-dqn", tmp_path / "log.json") == 0
    assert trial_log.restore_if_missing(fresh, "other", tmp_path / "none.json") == 0
    with pytest.raises(ConfigError, match="holds study 'learner-dqn', not 'other'"):
        trial_log.restore_if_missing(fresh, "other", tmp_path / "log.json")
    assert optuna.get_all_study_names(fresh) == ["learner-dqn"]
    assert len(optuna.load_study(study_name="learner-dqn", storage=fresh).trials) == 3


@pytest.mark.parametrize(
    "args, says",
    [
        (["save", "log.json", "--storage", "missing.db", "--study", "x"], "does not exist"),
        (["save", "log.json", "--storage", "lost.db", "--study", "other"], "no study 'other'"),
        (["save", "log.json", "--storage", "lost.db"], "needs study=NAME"),
        (["restore", "lost.db", "--storage", "new.db"], "is not a trial log"),
        (["keep", "log.json", "--storage", "lost.db"], "is invalid: use save or restore"),
        (
            ["save", "log.json", "--storage", "postgresql://x@127.0.0.1:1/x", "--study", "x"],
            "storage='postgresql://x@127.0.0.1:1/x' cannot be opened",
        ),  # fmt: skip
    ],
)
def test_bad_arguments_get_one_line(tmp_path, monkeypatch, capsys, args, says):
    monkeypatch.chdir(tmp_path)
    _searched(tmp_path, trials=1)
    with pytest.raises(SystemExit) as end:
        main(["trials", *args])
    err = capsys.readouterr().err
    assert end.value.code == 2 and err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "log.json").exists() and not (tmp_path / "missing.db").exists()
