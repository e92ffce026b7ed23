"""Several snake sizes in one run (snake_env.train.multi_n_env) and a JointPolicy run evaluated and
exported on sizes it was not trained on, end to end through snake-train, snake-eval and snake-export."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from snake_env.train.joint_features import base_size
from snake_env.train.multi_n_env import MultiNVecEnv
from tests.newest_ids import newest_id

FAMILY = newest_id("Snake")  # kwarg n_links


def test_padded_observations_and_only_real_torques_reach_the_env():
    envs = [MultiNVecEnv(FAMILY, [3, 5], 3, max_episode_steps=3) for _ in range(2)]
    actions = np.random.default_rng(0).uniform(-1, 1, (3, 3, 4))  # (step, env, joint)
    try:
        env = envs[0]
        assert [rows.stop - rows.start for rows in env.rows] == [2, 1]  # the smaller n first
        assert env.observation_space.shape == (base_size(env.layout, 4) + 4,) and env.action_space.shape == (4,)
        assert env.get_attr("n_links") == [3, 3, 5]
        outputs = []
        for k, venv in enumerate(envs):
            venv.seed(11)
            venv.reset()
            steps = []
            for step in actions:
                step = step.copy()
                if k == 1:  # padded torques (joints 3, 4 of the 3-link snakes) are garbage here
                    step[:2, 2:] = 1e3
                steps.append(venv.step(step))
            outputs.append(steps)
        for a, b in zip(*outputs):
            np.testing.assert_array_equal(a[0], b[0])  # observations
            np.testing.assert_array_equal(a[1], b[1])  # rewards
        obs, _, dones, infos = outputs[0][-1]
        np.testing.assert_array_equal(obs[:, -4:], [[1, 1, 0, 0], [1, 1, 0, 0], [1, 1, 1, 1]])  # the mask
        assert np.all(obs[:2, 2:4] == 0) and np.all(obs[:2, 10:12] == 0)  # padded joint angles and rates
        assert dones.all()  # 3-step episodes: the terminal observations are padded too
        assert all(info["terminal_observation"].shape == env.observation_space.shape for info in infos)
        assert all(env.observation_space.contains(o) for o in obs)
    finally:
        for venv in envs:
            venv.close()


TINY = {
    "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 1, "eval_freq": 1024},
    "sac": {"learning_starts": 64, "buffer_size": 2000, "batch_size": 32, "eval_freq": 256},
}


def write_config(path, algo) -> None:
    entry = {"policy": "JointPolicy", "policy_kwargs": "dict(hidden=8, layers=1)", "n_envs": 4,
             "normalize": {"norm_obs": False, "norm_reward": True}, "n_links_set": [3, 5],
             "env_kwargs": {"max_episode_steps": 50}, "n_eval_episodes": 1,
             "checkpoint_freq": 100000, **TINY[algo]}
    path.write_text(yaml.safe_dump({FAMILY: entry}))


@pytest.fixture(scope="module")
def multi_n_runs(tmp_path_factory):
    """Finished multi-n runs on n in {3, 5}: PPO 2048 steps, SAC 256 steps."""
    from snake_env.train.train import main

    root = tmp_path_factory.mktemp("multi_n")
    runs = {}
    for algo, steps in (("ppo", 2048), ("sac", 256)):
        write_config(root / f"{algo}.yaml", algo)
        runs[algo] = root / algo
        assert main(["--algo", algo, "--env", FAMILY, "--config", str(root / f"{algo}.yaml"), "--total-timesteps",
                     str(steps), "--run-dir", str(runs[algo]), "--no-progress-bar"]) == 0
    return runs


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_multi_n_run_evaluates_on_an_unseen_n(multi_n_runs, tmp_path, algo):
    from snake_env.train.evaluate import main as eval_main

    run = multi_n_runs[algo]
    config = yaml.safe_load((run / "config.yaml").read_text())
    assert config["n_links_set"] == [3, 5] and config["policy"] == "JointPolicy"
    assert (run / "eval" / "evaluations.npz").is_file()  # the padded eval env ran
    out = tmp_path / "eval.json"
    target = ["--env", newest_id("Snake8")] if algo == "ppo" else ["--env-kwarg", "n_links=4"]
    assert eval_main([str(run), *target, "--episodes", "1", "--max-steps", "20", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["episodes"][0]["length"] == 20 and np.isfinite(report["mean_forward_velocity"])
    assert report["env_id"] == (newest_id("Snake8") if algo == "ppo" else FAMILY)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_multi_n_run_exports_onnx_for_another_n(multi_n_runs, tmp_path, algo):
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    import gymnasium as gym

    from snake_env.agents.policy_loading import load_policy
    from snake_env.train.export import main as export_main, read_metadata

    run, env_id = multi_n_runs[algo], newest_id("Snake12")
    out = tmp_path / "snake12.onnx"
    assert export_main([str(run), "--env", env_id, "--out", str(out)]) == 0
    onnx.checker.check_model(onnx.load(str(out)), full_check=True)
    meta = read_metadata(out)
    assert meta["env_id"] == env_id and meta["n_links"] == "12" and meta["action_size"] == "11"
    env = gym.make(env_id)
    observations = []
    obs, _ = env.reset(seed=0)
    for _ in range(30):
        observations.append(obs)
        obs, *_ = env.step(env.action_space.sample())
    loaded = load_policy(run, env.observation_space, env.action_space, {"algo": algo})
    env.close()
    observations = np.asarray(observations, np.float32)
    expected = loaded.model.predict(observations, deterministic=True)[0]
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    np.testing.assert_allclose(session.run(None, {"obs": observations})[0], expected, rtol=0, atol=1e-5)


def test_other_tasks_and_mlp_runs_stay_refused(multi_n_runs, capsys):
    from snake_env.train.evaluate import main as eval_main

    with pytest.raises(SystemExit):
        eval_main([str(multi_n_runs["ppo"]), "--env", newest_id("SnakeCommand5"), "--episodes", "1"])
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the policy reads" in err


def test_transfer_table_over_sizes(multi_n_runs, tmp_path, capsys):
    """python -m snake_env.train.transfer: one row per size, trained sizes marked, ratio to the serpenoid."""
    from snake_env.train.transfer import main as transfer_main

    out = tmp_path / "transfer.json"
    assert transfer_main([str(multi_n_runs["ppo"]), "--sizes", "3", "8", "--episodes", "1", "--json", str(out),
                          "--plot", str(tmp_path / "transfer.png")]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["n_links"], r["trained_on"]) for r in rows] == [(3, True), (8, False)]
    for r in rows:
        assert r["ratio"] == pytest.approx(r["speed"] / r["serpenoid"]) and r["serpenoid"] > 0
        assert 0.0 <= r["sliding"] <= 1.0  # the share of wheel-steps that slid (v4's wheels)
    table = capsys.readouterr().out
    assert "| 8 | no |" in table and "| sliding |" in table
    assert (tmp_path / "transfer.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(SystemExit) as exit_info:
        transfer_main([str(tmp_path), "--sizes", "3", "--json", str(out)])
    assert exit_info.value.code == 2


def test_transfer_on_another_versions_physics(multi_n_runs, tmp_path, capsys):
    """--version vN: every size runs on that version's id, against the serpenoid searched on it; an unknown
    version is a one-line error that lists the registered ones."""
    from snake_env.train.evaluate import main as eval_main
    from snake_env.train.transfer import main as transfer_main

    newest = FAMILY.rsplit("-v", 1)[1]
    older = f"v{int(newest) - 1}"
    out = tmp_path / "transfer.json"
    assert transfer_main([str(multi_n_runs["ppo"]), "--sizes", "3", "--episodes", "1", "--json", str(out),
                          "--version", older]) == 0
    report = json.loads(out.read_text())
    assert report["version"] == older
    policy = json.loads((tmp_path / "transfer_cache" / older / "policy_n3_1.json").read_text())
    assert policy["env_id"] == f"snake_env/Snake3-{older}"
    direct = tmp_path / "serpenoid.json"
    assert eval_main(["--baseline", "serpenoid", "--env", f"snake_env/Snake3-{older}", "--episodes", "1",
                      "--json", str(direct)]) == 0
    assert report["rows"][0]["serpenoid"] == json.loads(direct.read_text())["mean_forward_velocity"]
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        transfer_main([str(multi_n_runs["ppo"]), "--sizes", "3", "--json", str(out), "--version", "v99"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and err.count("\n") == 1 and f"{older}, v{newest}" in err


def test_fine_tuning_starts_from_another_runs_weights(multi_n_runs, tmp_path, capsys):
    """snake-train --init-from: a JointPolicy trained on {3, 5} starts a Snake8 run with exactly its weights,
    and the run records where they came from."""
    import torch
    from stable_baselines3 import PPO

    from snake_env.train.train import build_model, load_initial_weights, main
    from snake_env.train import config as cfg
    from snake_env.train.envs import make_vec_env

    source = multi_n_runs["ppo"]
    write_config(tmp_path / "ppo.yaml", "ppo")
    entry = yaml.safe_load((tmp_path / "ppo.yaml").read_text())
    entry[newest_id("Snake8")] = {k: v for k, v in entry[FAMILY].items() if k != "n_links_set"}
    (tmp_path / "ppo.yaml").write_text(yaml.safe_dump(entry))
    config = cfg.build_config("ppo", newest_id("Snake8"), str(tmp_path / "ppo.yaml"), [], seed=1)
    venv = make_vec_env(config, 2, 1)
    model = build_model(config, venv, 0)
    load_initial_weights(model, source)
    trained = PPO.load(source / "model.zip", device="cpu").policy.state_dict()
    for name, value in model.policy.state_dict().items():
        assert torch.equal(value, trained[name]), name
    venv.close()
    run = tmp_path / "fine"
    assert main(["--algo", "ppo", "--env", newest_id("Snake8"), "--config", str(tmp_path / "ppo.yaml"),
                 "--total-timesteps", "256", "--run-dir", str(run), "--init-from", str(source),
                 "--no-progress-bar"]) == 0
    assert "initialized the policy from" in capsys.readouterr().out
    assert yaml.safe_load((run / "config.yaml").read_text())["init_from"] == str(source / "model.zip")


def test_init_from_weights_that_do_not_fit_is_a_one_line_error(ppo_run, tmp_path, capsys):
    from tests.train.conftest import train_args

    from snake_env.train.train import main

    for init, message in ((tmp_path / "missing", "init_from must be a run directory with a model.zip"),
                          (ppo_run, "its weights do not fit this run's policy")):
        args = train_args("ppo", tmp_path / f"run_{init.name}", 64, "--init-from", str(init))
        args[args.index("--env") + 1] = newest_id("Snake5")  # 4 joints against the source's 2: other shapes
        with pytest.raises(SystemExit) as exit_info:
            main(args)
        err = capsys.readouterr().err
        assert exit_info.value.code == 2 and err.count("\n") == 1 and message in err, err


def test_critic_warm_up_trains_only_the_value_path_then_releases_the_actor(multi_n_runs, tmp_path):
    """callback CriticWarmUp: a fine-tuning run's actor keeps the loaded weights for the warm-up while its
    critic changes; a warm-up shorter than the run releases the actor."""
    import torch
    from stable_baselines3 import PPO

    from snake_env.train.train import main

    source = multi_n_runs["ppo"]
    loaded = PPO.load(source / "model.zip", device="cpu").policy.state_dict()
    write_config(tmp_path / "ppo.yaml", "ppo")
    entry = yaml.safe_load((tmp_path / "ppo.yaml").read_text())
    single = {k: v for k, v in entry[FAMILY].items() if k != "n_links_set"}
    for steps, name in ((10_000, "held"), (256, "released")):
        single["callback"] = [{"snake_env.train.callbacks.CriticWarmUp": {"steps": steps}}]
        entry[newest_id("Snake8")] = single
        (tmp_path / "ppo.yaml").write_text(yaml.safe_dump(entry))
        run = tmp_path / name
        assert main(["--algo", "ppo", "--env", newest_id("Snake8"), "--config", str(tmp_path / "ppo.yaml"),
                     "--total-timesteps", "1024", "--run-dir", str(run), "--init-from", str(source),
                     "--no-progress-bar"]) == 0
        after = PPO.load(run / "model.zip", device="cpu").policy.state_dict()
        actor = [k for k in after if "value" not in k and "critic" not in k]
        critic = [k for k in after if k not in actor]
        assert actor and critic
        assert any(not torch.equal(after[k], loaded[k]) for k in critic)
        unchanged = all(torch.equal(after[k], loaded[k]) for k in actor)
        assert unchanged == (name == "held"), name
