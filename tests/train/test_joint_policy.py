"""The shared per-joint policy (snake_env.train.joint_policy): padding never changes real joints,
the mirror symmetry it promises, one-line config errors, PPO and SAC train on it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from snake_env.train import config as cfg
from snake_env.train.joint_features import PARITY, base_size
from snake_env.train.joint_policy import JointActorCriticPolicy, JointSACPolicy
from snake_env.train.multi_n_env import MultiNVecEnv
from tests.newest_ids import newest_id

FAMILY = newest_id("Snake")  # kwarg n_links
LR = lambda _: 1e-3  # noqa: E731


@pytest.fixture(scope="module")
def padded_env():
    """Snakes of 5 and 12 links in one padded env (3 + 3 sub-envs), after 20 random steps."""
    torch.set_num_threads(1)
    env = MultiNVecEnv(FAMILY, [5, 12], 6)
    env.seed(3)
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, *_ = env.step(rng.uniform(-1, 1, (6, env.max_joints)))
    yield env, obs
    env.close()


def unpadded(env, obs, group=0):
    """The rows of size group ``group`` as that snake's own (unpadded) observations."""
    rows = env.rows[group]
    return obs[rows][:, env._targets[group]]


def policies(env, algo, **options):
    """(policy for the padded env, the same weights for the n = 5 env alone)."""
    single = env.groups[0]
    cls = {"ppo": JointActorCriticPolicy, "sac": JointSACPolicy}[algo]
    torch.manual_seed(0)
    padded = cls(env.observation_space, env.action_space, LR, layout=env.layout, **options)
    return padded, padded.for_spaces(single.observation_space, single.action_space)


def mirrored(obs, layout, joints, masked):
    """The observation of the snake reflected about the x axis (phi, phidot, sin theta_1, thetadot_1 flip)."""
    out = np.array(obs, dtype=np.float64, copy=True)
    start = 0
    for name, size in layout:
        width = joints if size == "joint" else size
        if name in ("joint_angles", "joint_rates"):
            out[:, start:start + width] *= -1
        elif name in ("heading", "generalized_speeds"):
            out[:, start + 1] *= -1  # sin theta_1; thetadot_1
        start += width
    assert start + (joints if masked else 0) == out.shape[1]
    return out


def t(x):
    return torch.as_tensor(np.asarray(x), dtype=torch.float32)


def test_padding_never_changes_the_real_joints_ppo(padded_env):
    env, obs = padded_env
    padded, single = policies(env, "ppo", hidden=16)
    small = unpadded(env, obs)  # n = 5: 4 joints
    big = obs[env.rows[0]].copy()
    mask_start = base_size(env.layout, env.max_joints)
    garbage = np.random.default_rng(1).normal(size=big.shape) * 100
    pad_slots = np.ones(big.shape[1], bool)
    pad_slots[env._targets[0]] = False
    pad_slots[mask_start:] = False
    big[:, pad_slots] = garbage[:, pad_slots]  # whatever sits in padded slots is never read
    actions = np.random.default_rng(2).uniform(-1, 1, (len(small), env.max_joints))
    with torch.no_grad():
        mean_small, mean_big = single.action_mean(t(small)), padded.action_mean(t(big))
        torch.testing.assert_close(mean_big[:, :4], mean_small, rtol=0, atol=1e-6)
        assert torch.all(mean_big[:, 4:] == 0)
        v_small, logp_small, ent_small = single.evaluate_actions(t(small), t(actions[:, :4]))
        v_big, logp_big, ent_big = padded.evaluate_actions(t(big), t(actions))
        torch.testing.assert_close(v_big, v_small, rtol=0, atol=1e-5)
        torch.testing.assert_close(logp_big, logp_small, rtol=0, atol=1e-5)
        torch.testing.assert_close(ent_big, ent_small, rtol=0, atol=1e-5)
        sampled, _, _ = padded(t(big))
        assert torch.all(sampled[:, 4:] == 0)  # padded joints act 0
        # predict (SB3's acting path) on the whole padded batch: the n = 12 rows use all 11 joints
        full = padded.predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(full[env.rows[0], :4], mean_small.numpy().clip(-1, 1), atol=1e-6)
    assert np.all(full[env.rows[0], 4:] == 0) and np.any(full[env.rows[1], 4:] != 0)


def test_padding_never_changes_the_real_joints_sac(padded_env):
    env, obs = padded_env
    padded, single = policies(env, "sac", hidden=16)
    small, big = unpadded(env, obs), obs[env.rows[0]]
    actions = np.random.default_rng(2).uniform(-1, 1, (len(small), env.max_joints))
    with torch.no_grad():
        mean_s, log_std_s, _ = single.actor.get_action_dist_params(t(small))
        mean_b, log_std_b, _ = padded.actor.get_action_dist_params(t(big))
        torch.testing.assert_close(mean_b[:, :4], mean_s, rtol=0, atol=1e-6)
        torch.testing.assert_close(log_std_b[:, :4], log_std_s, rtol=0, atol=1e-6)
        for q_b, q_s in zip(padded.critic(t(big), t(actions)), single.critic(t(small), t(actions[:, :4]))):
            torch.testing.assert_close(q_b, q_s, rtol=0, atol=1e-5)
        sampled, _ = padded.actor.action_log_prob(t(big))
        assert torch.all(sampled[:, 4:] == 0)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_mirror_gives_opposite_torques(padded_env, algo):
    """Promised with mirror=True (the default): torques odd, value even, Q(Mx, -a) = Q(x, a)."""
    env, obs = padded_env
    padded, single = policies(env, algo, hidden=16)
    actions = np.random.default_rng(4).uniform(-1, 1, obs.shape[:1] + (env.max_joints,))
    cases = [(padded, obs, actions, env.max_joints, True),
             (single, unpadded(env, obs), actions[env.rows[0], :4], 4, False)]
    for policy, x, a, joints, masked in cases:
        mx = mirrored(x, env.layout, joints, masked)
        with torch.no_grad():
            if algo == "ppo":
                torch.testing.assert_close(policy.action_mean(t(mx)), -policy.action_mean(t(x)), rtol=0, atol=1e-6)
                torch.testing.assert_close(policy.predict_values(t(mx)), policy.predict_values(t(x)), rtol=0, atol=1e-5)
            else:
                mean, log_std, _ = policy.actor.get_action_dist_params(t(x))
                mean_m, log_std_m, _ = policy.actor.get_action_dist_params(t(mx))
                torch.testing.assert_close(mean_m, -mean, rtol=0, atol=1e-6)
                torch.testing.assert_close(log_std_m, log_std, rtol=0, atol=1e-6)
                for q, q_m in zip(policy.critic(t(x), t(a)), policy.critic(t(mx), t(-a))):
                    torch.testing.assert_close(q_m, q, rtol=0, atol=1e-5)
    # without the promise the network is free to break it
    free, _ = policies(env, algo, hidden=16, mirror=False)
    with torch.no_grad():
        x, mx = t(obs), t(mirrored(obs, env.layout, env.max_joints, True))
        if algo == "ppo":
            assert not torch.allclose(free.action_mean(mx), -free.action_mean(x), atol=1e-4)
        else:
            assert not torch.allclose(free.actor.get_action_dist_params(mx)[0],
                                      -free.actor.get_action_dist_params(x)[0], atol=1e-4)


def test_the_mirror_is_the_physical_reflection():
    """The observation map the promise uses is the reflection y -> -y of the snake's state
    (theta_k -> -theta_k, y -> -y, thetadot_1 -> -thetadot_1), and the physics keeps it: opposite
    torques from mirrored states give mirrored observations and the same reward."""
    import gymnasium as gym

    env = gym.make(newest_id("Snake5"))
    try:
        base = env.unwrapped
        layout = [[name, "joint" if name.startswith("joint") else size]
                  for name, size in base.observation_structure.items() if size and not name.startswith("skipped")]
        env.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(10):
            env.step(rng.uniform(-1, 1, 4))
        q, u = base.state
        q_m, u_m = q.copy(), u.copy()
        q_m[:5] *= -1
        q_m[6] *= -1
        u_m[1] *= -1
        obs, obs_m = base.set_state(q, u), base.set_state(q_m, u_m)
        np.testing.assert_allclose(obs_m[None], mirrored(obs[None], layout, 4, False), atol=1e-12)
        action = rng.uniform(-1, 1, 4)
        base.set_state(q, u)
        after, reward, *_ = env.step(action)
        base.set_state(q_m, u_m)
        after_m, reward_m, *_ = env.step(-action)
        np.testing.assert_allclose(after_m[None], mirrored(after[None], layout, 4, False), atol=1e-9)
        assert reward_m == pytest.approx(reward, abs=1e-9)
    finally:
        env.close()
    assert len(PARITY) == 9 and PARITY[-1] == 1.0  # the "joint exists" channel never flips


def joint_config(algo="ppo", **overrides):
    config = {"algo": algo, "env_id": FAMILY, "policy": "JointPolicy", "normalize": {"norm_obs": False},
              "policy_kwargs": {}}
    config.update(overrides)
    return config


@pytest.mark.parametrize("overrides, message", [
    ({"policy_kwargs": "dict(hiden=64)"}, "unknown JointPolicy policy_kwargs key(s) ['hiden'] for ppo"),
    ({"policy_kwargs": "dict(hidden=0)"}, "policy_kwargs.hidden must be a positive integer"),
    ({"policy_kwargs": "dict(kernel_size=4)"}, "policy_kwargs.kernel_size must be an odd positive integer"),
    ({"policy_kwargs": "dict(layers=2.5)"}, "policy_kwargs.layers must be a positive integer"),
    ({"policy_kwargs": "dict(rate_scale=-1.0)"}, "policy_kwargs.rate_scale must be a positive number"),
    ({"policy_kwargs": "dict(mirror='yes')"}, "policy_kwargs.mirror must be true or false"),
    ({"policy_kwargs": "dict(n_critics=2)"}, "unknown JointPolicy policy_kwargs key(s) ['n_critics'] for ppo"),
    ({"policy_kwargs": "dict(net_arch=[64])"}, "unknown JointPolicy policy_kwargs key(s) ['net_arch']"),
    ({"policy_kwargs": "dict(activation_fn='relu')"}, "policy_kwargs.activation_fn must be one of"),
    ({"policy_kwargs": "dict(layout=[['joint_angles', 3]])"}, "layout block 'joint_angles' must have size 'joint'"),
    ({"normalize": True}, "reads raw observations"),
    ({"policy": "MlpPolicy", "n_links_set": [5, 8]}, "n_links_set needs policy JointPolicy"),
    ({"n_links_set": [5, 1]}, "n_links_set must be a list of distinct integers >= 2"),
    ({"n_links_set": 5}, "n_links_set must be a list of distinct integers >= 2"),
    ({"n_links_set": [3, 5, 8], "n_envs": 2}, "n_envs must be at least the number of sizes in n_links_set (3)"),
    ({"n_links_set": [3, 5], "env_kwargs": {"n_links": 4}}, "env_kwargs n_links conflicts with n_links_set"),
])
def test_malformed_policy_config_is_a_one_line_error(overrides, message):
    with pytest.raises(cfg.ConfigError) as info:
        cfg.validate(joint_config(**overrides))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_sac_options_and_the_cli_error(capsys, tmp_path):
    cfg.validate(joint_config("sac", policy_kwargs="dict(n_critics=3, hidden=8)"))
    with pytest.raises(cfg.ConfigError, match=r"\['log_std_init'\] for sac"):
        cfg.validate(joint_config("sac", policy_kwargs="dict(log_std_init=-1.0)"))
    from snake_env.train.train import main

    config = tmp_path / "ppo.yaml"
    config.write_text(f"{FAMILY}:\n  policy: JointPolicy\n  normalize: {{norm_obs: false}}\n")
    with pytest.raises(SystemExit) as info:
        main(["--algo", "ppo", "--env", FAMILY, "--config", str(config), "--set", "policy_kwargs=dict(size=3)",
              "--run-dir", str(tmp_path / "never")])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown JointPolicy policy_kwargs key(s) ['size']" in err


def test_policy_class_from_config():
    from snake_env.train.joint_policy import JointActorCriticPolicy, JointSACPolicy

    for algo, cls in (("ppo", JointActorCriticPolicy), ("sac", JointSACPolicy)):
        config = cfg.validate(joint_config(algo, policy_kwargs="dict(activation_fn=nn.ELU, hidden=8)"))
        assert cfg.policy_for(config, None) is cls
        kwargs = cfg.torch_policy_kwargs(config)
        assert kwargs["activation_fn"] is torch.nn.ELU and kwargs["hidden"] == 8
        assert [name for name, _ in kwargs["layout"]] == ["joint_angles", "heading", "generalized_speeds",
                                                          "joint_rates"]
