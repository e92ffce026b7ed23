"""No silent blow-ups (issue 10): every accepted setting gives finite, checked values;
refinement meets its tolerance; the joint-limit barrier holds; single == vector."""

import dataclasses
import math
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from snake_env.benchmarks import fuzz
from snake_env.dynamics import compiled
from snake_env import physics
from snake_env.physics import stepping
from snake_env.physics import AUX_FAILED, AUX_KINETIC, AUX_REFINEMENTS, AUX_RESIDUAL, AUX_WORK
from snake_env.physics.config import max_stable_sim_dt
from snake_env.envs.snake import SnakeEnv
from snake_env.envs.vector import SnakeVectorEnv
from snake_env.physics.config import IDEAL_PHYSICS as IDEAL  # ideal torque sources, unlimited grip

KWARG_NAMES = ("sim_dt", "joint_limit", "max_torque", "mass", "length", "inertia", "energy_tolerance",
               "max_refinements", "integrator", "paper_model", "frame_skip")


@st.composite
def env_kwargs(draw):
    length = draw(st.floats(0.02, 1.5))
    mass = draw(st.floats(0.05, 20.0))
    return dict(
        n_links=draw(st.integers(2, 8)),
        max_torque=draw(st.floats(0.05, 200.0)),
        length=length,
        mass=mass,
        inertia=mass * length ** 2 / 12.0 * draw(st.floats(0.3, 3.0)),
        paper_model=draw(st.booleans()),
        sim_dt=draw(st.sampled_from([0.0005, 0.002, 0.005, 0.01, 0.02])),
        frame_skip=draw(st.integers(1, 4)),
        integrator=draw(st.sampled_from(["rk4_refined", "rk4"])),
    )


def _rate_bound(env):
    return physics.MAX_SUBSTEP_ANGLE / (env.sim_dt / 2 ** env.params.max_refinements)


def _check_step(env, obs, reward, info, k_prev):
    """Every value finite; an accepted step keeps the energy balance, no fold, resolved rates."""
    n = env.n_links
    assert np.isfinite(obs).all() and math.isfinite(reward)
    assert all(math.isfinite(info[k]) for k in ("kinetic_energy", "power", "x_position", "x_velocity"))
    if info["sim_failure"]:
        assert reward == 0.0
        return
    k1 = info["kinetic_energy"]
    residual = abs(k1 - k_prev - info["power"] * env.dt) / (max(k1, k_prev) + env.params.energy_floor)
    assert residual <= env.energy_tolerance + 1e-9
    assert np.all(np.abs(obs[: n - 1]) < compiled.FOLD_ANGLE)
    assert np.all(np.abs(obs[-(n - 1):]) <= _rate_bound(env)) and abs(obs[-n]) <= _rate_bound(env)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kwargs=env_kwargs(), seed=st.integers(0, 2 ** 16), bang=st.booleans())
def test_any_accepted_setting_gives_checked_values_and_single_equals_vector(kwargs, seed, bang):
    try:
        env = SnakeEnv(**kwargs)
    except ValueError as exc:
        assert any(name in str(exc) for name in KWARG_NAMES), str(exc)
        with pytest.raises(ValueError):
            SnakeVectorEnv(num_envs=1, **kwargs)
        return
    venv = SnakeVectorEnv(num_envs=1, **kwargs)
    obs, info = env.reset(seed=seed)
    vobs, _ = venv.reset(seed=seed)
    np.testing.assert_array_equal(obs, vobs[0])
    rng = np.random.default_rng(seed)
    k_prev = info["kinetic_energy"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for _ in range(40):
            a = rng.uniform(-1, 1, env.n_links - 1)
            if bang:
                a = np.sign(a)
            obs, reward, terminated, truncated, info = env.step(a)
            vobs, vreward, vterm, vtrunc, vinfo = venv.step(a[None])
            np.testing.assert_array_equal(obs, vobs[0])
            assert reward == vreward[0] and truncated == vtrunc[0] and terminated == vterm[0]
            assert info["sim_failure"] == vinfo["sim_failure"][0]
            _check_step(env, obs, reward, info, k_prev)
            k_prev = info["kinetic_energy"]
            if truncated:
                break


def _bang_bang(rng, shape, period=5):
    """Piecewise constant +-1 torques switching every ``period`` steps: drives joints into the limit."""
    steps = shape[0]
    signs = np.sign(rng.uniform(-1, 1, ((steps + period - 1) // period,) + shape[1:]))
    return np.repeat(signs, period, axis=0)[:steps]


def _step_errors(env, reference, rng, steps=40, B=32, period=3):
    """Per env step: the error of env's step against ``reference`` from the same state
    (max over theta_k (rad) and u relative to |u| + 1), the aux of env's step."""
    q, u, _, _ = physics.reset(env.params, rng.uniform(-0.1, 0.1, (B, env.n_links + 2)))
    errors, auxes = [], []
    for a in _bang_bang(rng, (steps, B, env.n_links - 1), period=period):
        torques = env.max_torque * a
        q1, u1, _, aux = physics.step(env.params, q, u, torques)
        qf, uf, _, auxf = physics.step(reference.params, q, u, torques)
        assert not auxf[:, AUX_FAILED].any()
        n = env.n_links
        err = np.maximum(np.abs(u1 - uf).max(axis=1) / (np.abs(uf).max(axis=1) + 1.0),
                         np.abs(q1[:, :n] - qf[:, :n]).max(axis=1))
        errors.append(err)
        auxes.append(aux)
        q, u = q1, u1
    return np.concatenate(errors), np.concatenate(auxes)


def test_refinement_meets_its_tolerance_against_a_fine_reference_on_a_stiff_case():
    """max_torque = 15 N m at sim_dt = 0.01 s (the largest torque accepted there; stiff barrier),
    bang-bang torques: against RK4 at sim_dt / 256, the refined steps keep the energy balance,
    their typical error is within the tolerance and far below plain RK4's."""
    kwargs = dict(n_links=5, max_torque=15.0, **IDEAL)
    reference = SnakeEnv(**kwargs, sim_dt=0.01 / 256, frame_skip=4 * 256, integrator="rk4")
    refined = SnakeEnv(**kwargs, error_tolerance=1e-3)
    plain = SnakeEnv(**kwargs, integrator="rk4", energy_tolerance=1.0)
    err_refined, aux = _step_errors(refined, reference, np.random.default_rng(3))
    err_plain, aux_plain = _step_errors(plain, reference, np.random.default_rng(3))
    ok = aux[:, AUX_FAILED] == 0
    assert ok.all()
    assert (aux[:, AUX_REFINEMENTS] > 0).mean() > 0.5  # the stiff case does need refinement
    assert np.all(aux[:, AUX_RESIDUAL] <= refined.energy_tolerance)
    assert np.median(err_refined) <= 1e-3  # measured 4.5e-4
    assert np.quantile(err_refined, 0.99) <= 0.05  # measured 0.018 (kinks of the barrier: see docs/reliability.md)
    assert np.median(err_refined) < np.median(err_plain) / 5
    assert np.quantile(err_refined, 0.99) < np.quantile(err_plain, 0.99) / 3


def _largest_accepted_torque(sim_dt):
    lo, hi = 1.0, 1e4
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        try:
            SnakeEnv(n_links=5, max_torque=mid, sim_dt=sim_dt)
            lo = mid
        except ValueError:
            hi = mid
    return lo


@pytest.mark.parametrize("sim_dt", [0.01, 0.001])
def test_joint_limit_holds_at_the_largest_accepted_torque(sim_dt):
    torque = _largest_accepted_torque(sim_dt)
    envs = SnakeVectorEnv(num_envs=32, n_links=5, max_torque=torque, sim_dt=sim_dt, frame_skip=round(0.04 / sim_dt))
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    worst = 0.0
    failures = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for a in _bang_bang(rng, (150, 32, 4), period=10):
            obs, _, _, _, info = envs.step(a)
            worst = max(worst, float(np.abs(obs[:, :4]).max()))
            failures += int(info["sim_failure"].sum())
    # the barrier stops the full torque (and the body's momentum, which reaches the joint
    # through the constraints) before the fold (170 deg); measured: 2.38 rad at
    # sim_dt = 0.01 s (15.6 N m)
    assert worst < compiled.FOLD_ANGLE - 0.3, (torque, worst)
    assert failures == 0


def test_refused_setting_names_the_argument_and_the_allowed_range():
    with pytest.raises(ValueError, match=r"sim_dt must be in \(0, [0-9.e-]+\] s .* got 0.01"):
        SnakeEnv(max_torque=100.0, sim_dt=0.01)  # explicit: honoured or refused
    with pytest.raises(ValueError, match=r"joint_limit must be .*<= 2.61799 \(rad, 150 deg at most"):
        SnakeEnv(joint_limit=3.0)
    with pytest.raises(ValueError, match="integrator must be one of"):
        SnakeEnv(integrator="euler")
    with pytest.raises(ValueError, match="energy_tolerance"):
        SnakeEnv(energy_tolerance=0.0)
    with pytest.raises(ValueError, match="max_refinements"):
        SnakeEnv(max_refinements=13)
    # the bound in the message is accepted, just above it is not
    with pytest.raises(ValueError) as exc:
        SnakeEnv(max_torque=100.0, sim_dt=0.01)
    bound = float(re.search(r"in \(0, ([0-9.e-]+)\] s", str(exc.value)).group(1))
    env = SnakeEnv(max_torque=100.0, sim_dt=bound * 0.999)
    assert max_stable_sim_dt(env.params, 100.0)[0] == pytest.approx(bound, rel=1e-2)
    with pytest.raises(ValueError, match="sim_dt"):
        SnakeEnv(max_torque=100.0, sim_dt=bound * 1.001)


@pytest.mark.parametrize("kwargs", [dict(max_torque=100.0), dict(n_links=12, max_torque=20.0),
                                    dict(length=0.05, mass=0.25, inertia=0.25 * 0.05 ** 2 / 12),
                                    dict(actuator="xh430_w350")])
def test_settings_rk4_cannot_step_at_the_default_sim_dt_run_in_substeps(kwargs):
    """sim_dt left at its default is divided into the fewest stable substeps; dt stays 0.04 s, and the
    steps are those of the explicit sim_dt = 0.01 / r with frame_skip 4 r, bit for bit (the no-slip wheels'
    RK4 step; the sliding wheels': next test)."""
    kwargs = {**kwargs, "wheel_model": "no_slip"}
    env = SnakeEnv(**kwargs)
    r = env.params.substeps
    bound = max_stable_sim_dt(env.params, env.max_torque)[0]
    assert r == math.ceil(0.01 / bound) >= 2 and env.dt == 0.04 and env.sim_dt == 0.01
    explicit = SnakeEnv(**kwargs, sim_dt=0.01 / r, frame_skip=4 * r)
    assert explicit.params.substeps == 1
    rng = np.random.default_rng(3)
    obs, _ = env.reset(seed=3)
    explicit.reset(seed=3)
    for _ in range(100):
        action = rng.uniform(-1, 1, env.action_space.shape)
        obs, reward, _, truncated, info = env.step(action)
        obs_e, reward_e, *_ = explicit.step(action)
        assert np.array_equal(obs, obs_e) and reward == reward_e
        assert np.all(np.isfinite(obs)) and not info["sim_failure"]
        assert env._batch.aux[0, AUX_RESIDUAL] <= env.energy_tolerance  # the work-energy balance holds


def test_failed_step_keeps_the_last_valid_state_with_reward_zero():
    """paper_model: a joint driven to the fold is a failure; obs is the pre-step obs, reward 0."""
    env = SnakeEnv(n_links=2, paper_model=True, max_torque=1.0)
    env.reset(seed=0)
    q = np.array([0.0, compiled.FOLD_ANGLE - 0.01, 0.0, 0.0])
    before = env.set_state(q, np.array([10.0, 0.0]))  # the joint opens further at ~17 rad/s
    with pytest.warns(RuntimeWarning, match="folded"):
        obs, reward, terminated, truncated, info = env.step(np.array([1.0]))
    assert info["sim_failure"] and truncated and not terminated
    assert reward == 0.0 and info["reward_ctrl"] == 0.0 and info["power"] == 0.0
    np.testing.assert_array_equal(obs, before)
    np.testing.assert_array_equal(env.state[0], q)


def test_energy_balance_holds_on_every_accepted_default_step():
    rng = np.random.default_rng(1)
    env = SnakeEnv()
    q, u, _, aux = physics.reset(env.params, rng.uniform(-0.1, 0.1, (64, 7)))
    for a in _bang_bang(rng, (100, 64, 4), period=3):
        k0 = aux[:, AUX_KINETIC]
        q, u, _, aux = physics.step(env.params, q, u, a)
        assert not aux[:, AUX_FAILED].any()
        residual = np.abs(aux[:, AUX_KINETIC] - k0 - aux[:, AUX_WORK]) / (
            np.maximum(aux[:, AUX_KINETIC], k0) + env.params.energy_floor)
        assert np.all(residual <= env.energy_tolerance)


def test_an_accurate_fold_fails_at_once_and_the_finest_substep_folds_too():
    """Paper model (no joint limits), bang-bang torques: a step that passes the accuracy checks
    but ends folded is a failure without refinement (v2), the pre-step state is kept, and the
    same step at the finest substep (sim_dt / 2^max_refinements) folds as well."""
    env = SnakeEnv(n_links=5, paper_model=True, max_torque=1.0)
    p = env.params
    scale = 2 ** p.max_refinements
    finest = dataclasses.replace(p, sim_dt=p.sim_dt / scale, frame_skip=p.frame_skip * scale, max_refinements=0)
    rng = np.random.default_rng(0)
    q, u, _, _ = physics.reset(p, rng.uniform(-0.1, 0.1, (64, 7)))
    refinements, finest_codes = [], []
    for _ in range(120):
        torques = np.sign(rng.uniform(-1.0, 1.0, (64, 4)))
        q1, u1, _, aux = physics.step(p, q, u, torques)
        folded = aux[:, AUX_FAILED] == physics.FAIL_FOLD
        if folded.any():
            assert np.array_equal(q1[folded], q[folded]) and np.array_equal(u1[folded], u[folded])
            _, _, _, aux_finest = physics.step(finest, q[folded], u[folded], torques[folded])
            finest_codes += list(aux_finest[:, AUX_FAILED])
            refinements += list(aux[folded, AUX_REFINEMENTS])
            q1[folded], u1[folded], _, _ = physics.reset(p, rng.uniform(-0.1, 0.1, (int(folded.sum()), 7)))
        q, u = q1, u1
    assert len(refinements) > 100  # the undamped snake folds often under bang-bang torques
    assert np.mean(np.array(refinements) == 0) > 0.9  # decided by the first attempt (measured 1024 of 1026)
    assert np.all(np.array(finest_codes) == physics.FAIL_FOLD)  # measured: every one of 1026


def _refined_step_by_whole_attempts(p, q0, u0, torques):
    """The refinement of the module doc written out: levels r = 1..max_refinements, each one
    whole attempt (no stop at the first substep over the error tolerance), judged by the
    env's own check. Returns (code, r, q, u, work)."""
    h = p.half_length
    k0, _, _ = stepping._measures(p.kernel_model, q0, u0)
    code = r = None
    for r in range(1, p.max_refinements + 1):
        q, u = q0.copy(), u0.copy()
        sub = 2 ** r
        work, err, _ = compiled.rk4_step_estimate(p.kernel_model, q, u, torques, p.sim_dt / sub, p.frame_skip * sub,
                                               p.error_tolerance, h[0], False)
        finite = bool(np.isfinite(q).all() and np.isfinite(u).all() and math.isfinite(work))
        k1, rate, fold = stepping._measures(p.kernel_model, q, u) if finite else (math.nan,) * 3
        code, _ = stepping._verdict(finite and math.isfinite(k1), err, k0, k1, work, rate, fold, p.sim_dt / sub,
                                   p.kernel_settings)
        if code == 0:
            return code, r, q, u, work
        if code == physics.FAIL_FOLD:
            break
    return code, r, q0, u0, 0.0


@pytest.mark.parametrize("n_links", [5, 30])
def test_refinement_stopping_a_rejected_attempt_early_accepts_the_same_step_bit_for_bit(n_links):
    """A refinement attempt stops at its first substep over the error tolerance (it is redone
    finer anyway); the accepted level, state and work equal those of whole attempts, bit for bit.
    Paper model with short light links (0.02 m, 0.05 kg, 10 N m at the largest accepted sim_dt):
    the settings of docs/reliability.md where most steps need 3 to 6 halvings."""
    kwargs = dict(n_links=n_links, paper_model=True, max_torque=10.0, length=0.02, mass=0.05,
                  inertia=0.05 * 0.02 ** 2 / 12.0)
    env, note = fuzz.make_env(kwargs, num_envs=1)
    assert "0.01 s refused" in note
    p = env.params
    rng = np.random.default_rng(1)
    q, u, _, _ = physics.reset(p, rng.uniform(-0.1, 0.1, (32, n_links + 2)))
    checked = refined_past_first_level = 0
    for a in _bang_bang(rng, (6, 32, n_links - 1), period=2):
        torques = 10.0 * a
        q1, u1, _, aux = physics.step(p, q, u, torques)
        for b in np.flatnonzero(aux[:, AUX_REFINEMENTS] > 0):
            code, r, qr, ur, work = _refined_step_by_whole_attempts(p, q[b], u[b], torques[b])
            assert (aux[b, AUX_FAILED], aux[b, AUX_REFINEMENTS]) == (code, r)
            np.testing.assert_array_equal(q1[b], qr)
            np.testing.assert_array_equal(u1[b], ur)
            assert aux[b, AUX_WORK] == work
            checked += 1
            refined_past_first_level += r > 1
        q, u = q1, u1
    assert checked > 20 and refined_past_first_level > 10  # levels below the accepted one were rejected


@pytest.mark.parametrize("kwargs", [dict(max_torque=100.0), dict(n_links=12, max_torque=20.0),
                                    dict(length=0.05, mass=0.25, inertia=0.25 * 0.05 ** 2 / 12),
                                    dict(actuator="xh430_w350")])
def test_the_same_settings_run_on_the_default_sliding_wheels(kwargs):
    """The settings above run on the default sliding wheels too: dt stays 0.04 s, the time stepping takes
    twice RK4's substeps where RK4 needs them (physics.sliding_wheels.substeps_per_step), and the steps are
    finite and keep the work-energy balance with friction's work."""
    from snake_env.physics.sliding_wheels import EULER_SUBSTEP_FACTOR, SUBSTEP, substeps_per_step

    env = SnakeEnv(**kwargs)
    assert env.config.wheel_model == "sliding" and env.dt == 0.04
    substeps = substeps_per_step(env.params)
    assert substeps == 4 * max(round(0.01 / SUBSTEP), EULER_SUBSTEP_FACTOR * env.params.substeps)
    rng = np.random.default_rng(3)
    env.reset(seed=3)
    for _ in range(100):
        obs, _, _, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        assert np.all(np.isfinite(obs)) and not info["sim_failure"]
        assert env._batch.aux[0, AUX_RESIDUAL] <= env.energy_tolerance
