"""The zoo: compact model files that load with their library's own ``load`` and act exactly
as the trained models, names and globs wherever a model path works, their refusals, and the
watch command's videos.

Trained at the tiny profile (one DQN, QR-DQN and PPO training, a few seconds each); the
reference each test compares against is the run folder's own model file.
"""

from __future__ import annotations

import re
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bgap.common.config import validate
from bgap.common.errors import ConfigError
from tests.commands import command
from tests.configs import compose

FAMILIES = ("dqn", "qrdqn", "ppo")


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """One tiny training per algorithm, validating twice so that a best checkpoint exists."""
    from bgap.experiments.train import train

    root = tmp_path_factory.mktemp("runs")
    made = {}
    for algo in FAMILIES:
        cfg = validate(
            compose(
                "train",
                [
                    f"agent={algo}",
                    "profile=tiny",
                    "profile.train_steps=400",
                    "env=sparse",
                    "profile.eval_every_episodes=2",
                    "profile.eval_during_training=2",
                    "backend=vector",
                    f"run_dir={root}/{algo}/sparse/sparse-behavior_rich-s0",
                ],
            )
        )
        made[algo] = train(cfg, progress=False)
    return made


@pytest.fixture(scope="module")
def zoo_dir(runs, tmp_path_factory) -> Path:
    from bgap.experiments.zoo import export

    zoo = tmp_path_factory.mktemp("zoo")
    for algo, run in runs.items():
        export(run, algo, zoo / algo / "sparse")
    return zoo


@pytest.fixture(autouse=True)
def _zoo_env(zoo_dir, monkeypatch):
    monkeypatch.setenv("BGAP_ZOO", str(zoo_dir))


def recorded_observations(density: str = "sparse", n: int = 1000) -> np.ndarray:
    """``n`` observations recorded in the study's traffic of ``density`` (mix 0.5), 50
    seeded episodes played with random meta-actions on the vector backend."""
    from bgap.sim.simulators import make_vector_env

    cfg = validate(compose("evaluate", [f"env={density}", "backend=vector"]))
    from bgap.traffic.scenario import env_config

    venv = make_vector_env(env_config(cfg), 50, "vector")
    obs, _ = venv.reset(seed=list(range(50)))
    rng = np.random.default_rng(0)
    seen = [obs]
    while sum(len(o) for o in seen) < n:
        obs, *_ = venv.step(rng.integers(5, size=50))
        seen.append(obs)
    venv.close()
    return np.concatenate(seen)[:n]


def same_actions(a, b, obs: np.ndarray) -> None:
    """Two policy specs pick the same greedy action on every observation (observation
    options' columns added as when they play)."""
    from bgap.agents.policies import as_policy

    rngs = [np.random.default_rng(0)] * len(obs)
    np.testing.assert_array_equal(as_policy(a)[0](obs, rngs), as_policy(b)[0](obs, rngs))


@pytest.mark.parametrize("algo", FAMILIES)
def test_a_zoo_policy_loads_with_its_librarys_own_load_and_acts_as_the_trained_model(
    algo, runs, zoo_dir
):
    """Strict load by SB3's (or sb3-contrib's) own class; the same greedy action as the run
    folder's best model on 1,000 observations; the optimizer's moments dropped."""
    import sb3_contrib
    import stable_baselines3 as sb3

    from bgap.common.runs import model_file

    cls = {"dqn": sb3.DQN, "ppo": sb3.PPO, "qrdqn": sb3_contrib.QRDQN}[algo]
    archive = zoo_dir / algo / "sparse" / "behavior_rich" / "s0.zip"
    source = model_file(runs[algo], "best")
    assert source.name == "best_model.zip"
    compact, original = cls.load(archive, device="cpu"), cls.load(source, device="cpu")
    same_actions(compact, original, recorded_observations())
    assert compact.policy.optimizer.state_dict()["state"] == {}
    assert original.policy.optimizer.state_dict()["state"] != {}
    assert archive.stat().st_size < source.stat().st_size


def test_exporting_again_writes_the_same_bytes_with_fixed_timestamps(runs, zoo_dir, tmp_path):
    from bgap.experiments.zoo import export

    again = export(runs["dqn"], "dqn", tmp_path / "dqn" / "sparse")
    first = zoo_dir / "dqn" / "sparse" / "behavior_rich" / "s0.zip"
    assert again.read_bytes() == first.read_bytes()
    assert again.with_suffix(".yaml").read_text() == first.with_suffix(".yaml").read_text()
    with zipfile.ZipFile(first) as archive:
        assert {i.date_time for i in archive.infolist()} == {(1980, 1, 1, 0, 0, 0)}
        assert "system_info.txt" not in archive.namelist()


def test_the_card_records_what_the_run_folder_says(runs, zoo_dir):
    import json

    import yaml

    card = yaml.safe_load((zoo_dir / "ppo/sparse/behavior_rich/s0.yaml").read_text())
    best = json.loads((runs["ppo"] / "best.json").read_text())
    assert card["name"] == "zoo:ppo/sparse/behavior_rich/s0"
    assert card["policy"] == "ppo/sparse/sparse-behavior_rich-s0"
    assert (card["algorithm"], card["seed"], card["density"]) == ("ppo", 0, "sparse")
    assert card["checkpoint"]["kept"] == "best"
    assert card["checkpoint"]["validation"]["episodes"] == best["episodes"]
    assert card["records"]["chosen_collision_pct"] == best["collision_pct"]
    assert card["played_under"]["observed_vehicles"] == 5


def test_names_and_globs_resolve_and_mistakes_are_one_line(zoo_dir):
    from bgap.agents import zoo

    assert [p.parent.parent.parent.name for p in zoo.resolve("zoo:*/sparse/*/s0")] == sorted(
        FAMILIES
    )
    assert zoo.resolve_one("zoo:ppo/sparse/behavior_rich/s0").name == "s0.zip"
    for spec, message in [
        ("zoo:ppo/sparse/behavior_rich/s9", "is not in the zoo"),
        ("zoo:*/dense/*/*", "glob matches nothing"),
        ("zoo:ppo", "is not a zoo name"),
    ]:
        with pytest.raises(ConfigError, match=message) as err:
            zoo.resolve(spec)
        assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match="names 3 policies"):
        zoo.resolve_one("zoo:*/sparse/behavior_rich/s0")


def test_a_damaged_zoo_file_is_refused_in_one_line(zoo_dir, tmp_path, monkeypatch):
    import shutil

    from bgap.agents.policies import load_model

    copy = tmp_path / "zoo"
    shutil.copytree(zoo_dir, copy)
    archive = copy / "dqn/sparse/behavior_rich/s0.zip"
    archive.write_bytes(archive.read_bytes()[: archive.stat().st_size // 2])
    monkeypatch.setenv("BGAP_ZOO", str(copy))
    with pytest.raises(ConfigError, match="git checkout -- zoo") as err:
        load_model("zoo:dqn/sparse/behavior_rich/s0")
    assert "\n" not in str(err.value)


def test_evaluating_a_zoo_name_plays_the_same_episodes_as_its_run_folder(
    runs, tmp_path, monkeypatch, capsys
):
    """Row for row, every column but the policy's name; models.csv says the same of both."""
    common = ["baselines=[]", "backend=vector", "profile.eval_episodes=6", "mix=0.4"]
    status, _, err = command(
        "bgap.evaluate",
        ["models=[zoo:dqn/sparse/*/*]", *common, f"out={tmp_path}/zoo"],
        monkeypatch,
        capsys,
    )
    assert status == 0, err
    status, _, err = command(
        "bgap.evaluate",
        [f"models=[{runs['dqn'].parent.parent}]", *common, f"out={tmp_path}/run"],
        monkeypatch,
        capsys,
    )
    assert status == 0, err
    a = pd.read_parquet(tmp_path / "zoo/episodes.parquet")
    b = pd.read_parquet(tmp_path / "run/episodes.parquet")
    assert set(a.policy) == {"dqn/sparse/sparse-behavior_rich-s0"}  # the study's naming
    assert len(a) == 6
    pd.testing.assert_frame_equal(a.drop(columns="policy"), b.drop(columns="policy"))
    ma, mb = pd.read_csv(tmp_path / "zoo/models.csv"), pd.read_csv(tmp_path / "run/models.csv")
    pd.testing.assert_frame_equal(ma.drop(columns="policy"), mb.drop(columns="policy"))


@pytest.mark.parametrize(
    "module,args,message",
    [
        (
            "bgap.simulate",
            ["env=dense", "policy=zoo:dqn/sparse/behavior_rich/s0"],
            "reads 5 observed vehicles, this environment observes 40",
        ),
        (
            "bgap.evaluate",
            ["models=[zoo:dqn/sparse/behavior_rich/s0]", "env=dense", "baselines=[]"],
            "observes 5 vehicles",
        ),
        ("bgap.simulate", ["policy=zoo:dqn/sparse/behavior_rich/s7"], "is not in the zoo"),
        (
            "bgap.simulate",
            ["env=dense", "policy={zoo}/ppo/sparse/behavior_rich/s0.zip"],
            "reads 5 observed vehicles, this environment observes 40",
        ),
        ("bgap.evaluate", ["models=[zoo:nope/*/*/*]"], "glob matches nothing"),
        (
            "bgap.watch",
            ["policy=zoo:dqn/sparse/behavior_rich/s0", "env.ego_speeds=[10,20,30]"],
            r"trained with ego_speeds=\[10,15,20,25,30\], this environment has "
            r"ego_speeds=\[10,20,30\]",
        ),
        (
            "bgap.watch",
            ["policy=zoo:dqn/sparse/behavior_rich/s0", "env=dense", "zoo_override=true"],
            "reads 5 observed vehicles",
        ),
        (
            "bgap.evaluate",
            ["models=[zoo:dqn/sparse/behavior_rich/s0]", "env.ego_speeds=[10,20,30]"],
            r"trained with ego_speeds=\[10,15,20,25,30\], this environment has "
            r"ego_speeds=\[10,20,30\]: .*under the settings its card records",
        ),
        (
            "bgap.evaluate",
            ["models=[zoo:dqn/sparse/behavior_rich/s0]", "env.policy_frequency=3"],
            "trained with policy_frequency=1, this environment has policy_frequency=3",
        ),
        ("bgap.evaluate", ["models=[]", "baselines=[]"], "nothing to evaluate"),
        (
            "bgap.watch",
            ["policy=rule", "traffic=replay", "traffic.table=missing.parquet"],
            "replayed traffic cannot be watched yet",
        ),
        (
            "bgap.simulate",
            ["traffic=replay", "traffic.table=t.parquet", "backend=highway"],
            "a replayed table is its own recording",
        ),
        (
            "bgap.simulate",
            ["traffic=replay", "traffic.table=t.parquet", "backend=vector"],
            "play a policy in it with bgap.evaluate traffic=replay",
        ),
    ],
)
def test_refusals_are_one_line_and_status_2(
    module, args, message, zoo_dir, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    args = [a.replace("{zoo}", str(zoo_dir)) for a in args]
    pd.DataFrame({"x": [0.0]}).to_parquet(tmp_path / "t.parquet")
    status, _, err = command(module, args, monkeypatch, capsys)
    assert status == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert message in err or re.search(message, err), err


def test_two_models_of_one_name_or_a_baselines_name_are_refused(
    runs, tmp_path, monkeypatch, capsys
):
    import shutil

    for parent in ("a", "b"):
        shutil.copytree(runs["dqn"], tmp_path / parent / "rule")
    monkeypatch.chdir(tmp_path)
    status, _, err = command(
        "bgap.evaluate", ["models=[a/rule,b/rule]", "baselines=[]"], monkeypatch, capsys
    )
    assert status == 2 and "gives a policy named 'rule', as does" in err, err
    status, _, err = command(
        "bgap.evaluate", ["models=[a/rule]", "baselines=[rule]"], monkeypatch, capsys
    )
    assert status == 2 and "as does the baseline" in err, err


def test_watch_writes_one_picture_per_simulation_frame_and_reports_the_episode(
    tmp_path, monkeypatch, capsys
):
    """A 6-second episode: 1 + 15 x 6 pictures at 15 per second, the first not blank (the
    ego's green box is in it); the printed outcome is episodes.csv's."""
    import imageio.v2 as imageio

    from bgap.sim.film import COLOURS

    monkeypatch.chdir(tmp_path)
    args = ["policy=zoo:dqn/sparse/behavior_rich/s0", "env.duration=6", "out=w"]
    status, out, err = command("bgap.watch", args, monkeypatch, capsys)
    assert status == 0, err
    episodes = pd.read_csv(tmp_path / "w/episodes.csv")
    steps = int(episodes.steps.iloc[0])
    reader = imageio.get_reader(tmp_path / "w/episode0.mp4")
    assert reader.get_meta_data()["fps"] == 15
    assert reader.count_frames() == 1 + 15 * steps
    first = reader.get_data(0).astype(int)
    assert first.std() > 10
    green = np.abs(first - np.array(COLOURS["ego"])).sum(axis=2) < 60  # H.264 shifts colours
    assert green.sum() > 100
    assert f"after {steps} steps" in out and "episode0.mp4" in out


def test_watch_writes_a_gif_where_imageio_ffmpeg_is_missing(tmp_path, monkeypatch, capsys):
    import imageio.v2 as imageio

    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    args = ["policy=rule", "env.duration=2", "out=g"]
    status, out, err = command("bgap.watch", args, monkeypatch, capsys)
    assert status == 0, err
    assert "writing GIF" in out
    assert len(imageio.mimread(tmp_path / "g/episode0.gif")) == 1 + 15 * 2


def test_the_film_draws_each_vehicle_where_the_table_puts_it():
    """A hand-made frame: the ego at x=100 in lane 1, an aggressive car 20 m ahead in lane
    0; their boxes' centres in pixels follow the view's scale and offset."""
    from bgap.sim import film

    table = pd.DataFrame(
        {
            "frame": [0, 0],
            "vehicle_id": [0, 1],
            "is_ego": [True, False],
            "label": ["ego", "aggressive"],
            "x": [100.0, 120.0],
            "y": [4.0, 0.0],
            "crashed": [False, False],
        }
    )
    (image,) = film.frames(table, lanes=4)
    assert image.shape == (film.height(4), film.WIDTH, 3) and image.shape[0] % 16 == 0
    for x, y, colour in [(100.0, 4.0, "ego"), (120.0, 0.0, "aggressive")]:
        px = int(round(film.BEHIND * film.WIDTH + (x - 100.0) * film.SCALE))
        top = (image.shape[0] - int(round(16 * film.SCALE))) // 2
        py = int(round(top + (y + 2.0) * film.SCALE))
        assert tuple(image[py, px]) == film.COLOURS[colour]


def test_the_zoo_in_the_repository_loads_and_matches_its_cards():
    """Every committed zoo policy has its card, the card names the file, and the file loads
    as the card's algorithm with the network it records."""
    import sb3_contrib
    import stable_baselines3 as sb3

    from bgap.agents import zoo

    classes = {"dqn": sb3.DQN, "ppo": sb3.PPO, "qrdqn": sb3_contrib.QRDQN}
    root = Path(__file__).resolve().parent.parent / "zoo"
    for archive in zoo.entries(root):
        card = zoo.card(archive)
        assert card["name"] == zoo.name_of(archive, root)
        model = classes[card["algorithm"]].load(archive, device="cpu")  # the library's own
        rows = model.observation_space.shape[0]
        assert rows == card["played_under"]["observed_vehicles"]


@pytest.mark.slow
def test_every_zoo_policy_acts_as_the_run_folder_model_it_came_from():
    """Where the pipeline's run folders exist (the machine that trained them): each zoo
    policy picks the run folder's model's action on 1,000 recorded observations."""
    from bgap.agents import zoo
    from bgap.common.runs import model_file

    root = Path(__file__).resolve().parent.parent
    checked = 0
    for archive in zoo.entries(root / "zoo"):
        card = zoo.card(archive)
        arm, density, run = card["policy"].split("/")
        folder = root / "outputs/pipeline/runs" / arm / density / run
        if not folder.exists():
            continue
        same_actions(str(archive), str(model_file(folder, "best")), recorded_observations(density))
        checked += 1
    if not checked:
        pytest.skip("no run folder of a zoo policy on this machine")


def test_a_model_on_the_paper_grid_says_which_cells_it_skips_and_folders_never_clash(
    tmp_path, monkeypatch, capsys
):
    """A sparse model on the paper's grid plays the 21 sparse cells only, and says so; the
    default output folder is named by the settings, so the next model's evaluation is not
    refused as 'other settings'."""
    monkeypatch.chdir(tmp_path)
    common = ["baselines=[idle]", "grid=paper", "backend=vector", "profile.eval_episodes=1"]
    outs = []
    for name in ("dqn", "ppo"):
        status, out, err = command(
            "bgap.evaluate", [f"models=[zoo:{name}/sparse/*/*]", *common], monkeypatch, capsys
        )
        assert status == 0, err
        assert "plays only the cells of its own density (sparse): 21 cells of dense skipped" in out
        assert " 63/63 " in err  # the progress counts the episodes played: 21 + 2 x 21 idle
        outs.append(next(line for line in out.splitlines() if line.startswith("results in")))
    assert outs[0] != outs[1]
    episodes = pd.read_parquet(Path(outs[1].split()[-1]) / "episodes.parquet")
    model = episodes[episodes.policy != "idle"]
    assert set(model.density) == {"sparse"} and len(model) == 21
    assert len(episodes[episodes.policy == "idle"]) == 42


@pytest.mark.parametrize(
    "module,config,args",
    [
        ("bgap.simulate", "simulate", ["episodes=1", "env.duration=2", "mix=0.3", "out=o"]),
        (
            "bgap.evaluate",
            "evaluate",
            ["baselines=[idle]", "profile.eval_episodes=1", "backend=vector", "radius=90", "out=o"],
        ),
        ("bgap.watch", "watch", ["policy=rule", "env.duration=2", "behavior=stock", "out=o"]),
        ("bgap.zoo", "zoo", ["runs={runs}", "arm=dqn", "out=o"]),
    ],
)
def test_the_saved_config_is_the_composed_config_the_command_used(
    module, config, args, runs, tmp_path, monkeypatch, capsys
):
    """Each command's ``config.yaml`` (where it writes one) is exactly the config composed
    from its command line: nothing dropped, defaulted or added on the way."""
    import yaml
    from omegaconf import OmegaConf

    from bgap.common import config as plumbing
    from bgap.datasets.config import SCHEMAS as DATASETS
    from bgap.experiments.config import SCHEMAS as EXPERIMENTS
    from bgap.experiments.watch import SCHEMAS as WATCH
    from bgap.experiments.zoo import SCHEMAS as ZOO

    monkeypatch.chdir(tmp_path)
    args = [a.replace("{runs}", str(runs["dqn"])) for a in args]
    status, _, err = command(module, args, monkeypatch, capsys)
    assert status == 0, err
    schemas = {"simulate": DATASETS, "evaluate": EXPERIMENTS, "watch": WATCH, "zoo": ZOO}
    composed = plumbing.compose(config, args, schemas[config])
    expected = OmegaConf.to_container(composed, resolve=True)
    saved = tmp_path / "o" / "config.yaml"
    if not saved.exists():  # bgap.zoo writes the zoo's files only: its card records the run
        assert config == "zoo" and (tmp_path / "o/behavior_rich/s0.yaml").exists()
        return
    assert yaml.safe_load(saved.read_text()) == expected


@pytest.mark.slow
@pytest.mark.parametrize("density", ["sparse", "dense"])
def test_a_fresh_clone_replays_a_committed_cell_from_the_zoo_row_for_row(
    density, tmp_path, monkeypatch, capsys
):
    """No DVC cache, no run folder: the committed zoo's seed-0 behaviour-rich policy of the
    main arm, evaluated on one committed cell (mix 0.5, radius 180), gives that cell's
    committed episodes row for row, every column equal, under the study's policy name."""
    root = Path(__file__).resolve().parent.parent
    folder = root / "results/evaluation/main/paper"
    if not (folder / "inputs.json").exists():
        pytest.skip("the committed evaluation of the main arm predates the zoo")
    monkeypatch.setenv("BGAP_ZOO", str(root / "zoo"))
    name = f"main/{density}/behavior_rich/s0"
    if not (root / "zoo" / f"{name}.zip").exists():
        pytest.skip(f"zoo:{name} is not committed yet")
    committed = pd.read_parquet(folder / "episodes.parquet")
    committed = committed[
        (committed.policy == f"main/{density}/{density}-behavior_rich-s0")
        & (committed.density == density)
        & np.isclose(committed.mix, 0.5)
        & np.isclose(committed.radius, 180.0)
    ].reset_index(drop=True)
    assert len(committed) == 100
    status, _, err = command(
        "bgap.evaluate",
        [
            f"models=[zoo:{name}]",
            "baselines=[]",
            f"env={density}",
            "mix=0.5",
            "radius=180",
            "behavior=paper",
            "backend=vector",
            "profile.eval_episodes=100",
            f"out={tmp_path}",
        ],
        monkeypatch,
        capsys,
    )
    assert status == 0, err
    replayed = pd.read_parquet(tmp_path / "episodes.parquet")
    pd.testing.assert_frame_equal(replayed[committed.columns], committed)
