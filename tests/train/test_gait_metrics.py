"""Gait metrics of snake-eval: the spectrum, flip and rate arithmetic on known signals, and the
searched serpenoid's metrics against its own parameters and an independent joint-rate computation."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.physics.config import sliding
from snake_env.controllers import SerpenoidController, load_params
from snake_env.envs.hud import episode_lines
from snake_env.train.evaluate import main as eval_main
from snake_env.train.gait_metrics import (REFERENCE_FRICTION, GaitRecorder, dominant_frequency, sign_flip_share,
                                         summarize_gait)

DT = 0.04  # s, the env step


def test_dominant_frequency_of_known_signals():
    t = np.arange(1000) * DT
    two_hz = np.stack([np.sin(2 * np.pi * 2.0 * t + k) for k in range(4)], axis=1)
    assert dominant_frequency(two_hz, DT) == pytest.approx(2.0)
    # a weaker 5 Hz component does not win; a bang-bang joint peaks at the Nyquist frequency
    assert dominant_frequency(two_hz + 0.3 * np.sin(2 * np.pi * 5.0 * t)[:, None], DT) == pytest.approx(2.0)
    chatter = np.where(np.arange(1000) % 2 == 0, 0.1, -0.1)[:, None]
    assert dominant_frequency(chatter, DT) == pytest.approx(1 / (2 * DT))
    assert dominant_frequency(np.ones((50, 3)), DT) == 0.0  # no bending, no gait
    assert math.isnan(dominant_frequency(np.zeros((3, 2)), DT))


def test_the_cone_share_counts_a_wheel_held_at_its_grip_as_inside():
    """A wheel the traction limit holds at mu m g sits up to a few ulps above it; only a force beyond
    SLIP_TOLERANCE of the grip counts as outside the cone."""
    load = np.array([9.81, 4.905])
    recorder = GaitRecorder(DT, wheel_load=load, wheel_friction=0.8)
    state = (np.zeros(1), np.zeros(1), np.zeros(1))
    held = 0.8 * load * (1.0 + 4.4e-16)  # what the traction limit's rounding gives (measured, test_traction.py)
    assert np.all(held / load > 0.8)  # the rule |lambda| > mu m g counted these as sliding
    for force in (held, 0.5 * held, 0.8 * load * (1.0 + 1e-6)):  # the last: a motion's own excess
        recorder.add(state, 0.0, force)
    assert recorder.metrics()["outside_friction_cone_share"] == pytest.approx(2 / 6)


def test_sign_flip_share_is_the_worst_joint():
    steps = np.arange(100)
    torques = np.stack([np.ones(100), np.where(steps % 2 == 0, 1.0, -1.0), np.where(steps % 4 < 2, 1.0, -1.0)],
                       axis=1)
    assert sign_flip_share(torques) == pytest.approx(1.0)
    assert sign_flip_share(torques[:, [0]]) == 0.0
    assert sign_flip_share(torques[:, [2]]) == pytest.approx(49 / 99)
    assert sign_flip_share(np.zeros((10, 2))) == 0.0  # zero torque is no flip


def test_summary_takes_means_and_the_largest_peaks():
    recorder = GaitRecorder(DT)
    for k in range(8):
        recorder.add((np.array([math.sin(k)]), np.array([k - 3.0]), np.array([(-1.0) ** k])), actuator_power=k)
    one = recorder.metrics()
    assert one["peak_joint_rate"] == 4.0 and one["torque_sign_flip_share"] == 1.0
    assert one["mean_power"] == 3.5 and one["peak_power"] == 7.0
    summary = summarize_gait([one, {**one, "peak_joint_rate": 9.0, "mean_power": 1.5}])
    assert summary["max_peak_joint_rate"] == 9.0 and summary["mean_power"] == 2.5
    lines = episode_lines(1.0, 0.5, 2.0, 3.0, gait=one)
    assert any(line.startswith("GAIT") and line.endswith("HZ") for line in lines)
    assert "FLIPS     100%" in lines


def test_serpenoid_gait_metrics_match_its_parameters_and_the_state(tmp_path):
    env_id, steps = "snake_env/Snake5-v2", 250
    out = tmp_path / "serpenoid.json"
    assert eval_main(["--baseline", "serpenoid", "--env", env_id, "--episodes", "1", "--max-steps", str(steps),
                      "--json", str(out)]) == 0
    episode = json.loads(out.read_text())["episodes"][0]
    params, _ = load_params(env_id)
    # the PD tracks the serpenoid: the joints oscillate at its frequency, within one spectral bin
    assert episode["dominant_joint_frequency"] == pytest.approx(params.frequency / (2 * np.pi), abs=1 / (steps * DT))
    # the same episode again, joint rates from the dynamics model's link rates (eq. 7)
    env = gym.make(env_id)
    base = env.unwrapped
    controller = SerpenoidController(params, 5, base.max_torque, base.dt)
    obs, _ = env.reset(seed=0)
    peak, signs, demand = 0.0, [], []
    for _ in range(steps):
        obs, _, _, _, info = env.step(controller.act(obs))
        demand.append(np.abs(base.wheel_lateral_forces()) / (base.mass * 9.81))
        q, u = base.state
        _, omega = base.model.link_velocities(q, u)
        peak = max(peak, float(np.max(np.abs(np.diff(omega)))))
        signs.append(np.sign(base.joint_state()[2]))
    assert episode["peak_joint_rate"] == pytest.approx(peak, rel=1e-9)
    flips = (np.asarray(signs)[1:] * np.asarray(signs)[:-1] < 0).mean(axis=0).max()
    assert episode["torque_sign_flip_share"] == pytest.approx(flips)
    assert 0.0 < episode["torque_sign_flip_share"] < 0.5  # a 4 Hz gait flips each torque twice a period
    # grip: |lambda| / (m g) over all wheel-steps; on v2's unlimited grip the cone is the default wheels'
    # (mu = REFERENCE_FRICTION = 0.8), which the searched v2 gait leaves often (79 % measured)
    assert episode["median_grip_demand"] == pytest.approx(np.median(demand), rel=1e-12)
    assert episode["outside_friction_cone_share"] == pytest.approx(np.mean(sliding(np.asarray(demand),
                                                                            REFERENCE_FRICTION)))
    assert 0.3 < episode["outside_friction_cone_share"] < 1.0


def test_wheel_slip_share_counts_the_flagged_wheel_steps():
    """On sliding wheels every force is within the grip, so the cone share is 0; the slip share counts the
    wheel-steps the env flags as sliding. Without flags (unlimited grip) it is nan."""
    recorder = GaitRecorder(DT, np.full(3, 9.81), 0.8)
    state = (np.zeros(2), np.zeros(2), np.ones(2))
    grip = 0.8 * 9.81
    recorder.add(state, 1.0, np.array([grip, -grip, 0.1]), np.array([True, False, False]))
    recorder.add(state, 1.0, np.array([grip, 0.2, 0.1]), np.array([True, True, False]))
    metrics = recorder.metrics()
    assert metrics["outside_friction_cone_share"] == 0.0
    assert metrics["wheel_slip_share"] == pytest.approx(3 / 6)
    unflagged = GaitRecorder(DT)
    unflagged.add(state, 1.0)
    assert math.isnan(unflagged.metrics()["wheel_slip_share"])


def test_eval_on_sliding_wheels_reports_the_slip_share(tmp_path):
    out = tmp_path / "eval.json"
    eval_main(["--baseline", "serpenoid", "--env", "snake_env/Snake5-v3", "--episodes", "1", "--max-steps", "30",
               "--env-kwarg", "wheel_model=sliding", "--json", str(out)])
    summary = json.loads(out.read_text())
    assert 0.0 < summary["mean_wheel_slip_share"] < 1.0  # the serpenoid's start slides some wheels
    assert summary["mean_outside_friction_cone_share"] == 0.0


def test_hud_shows_the_flagged_share_where_the_env_flags_wheels():
    gait = {"outside_friction_cone_share": 0.0, "wheel_slip_share": 0.42}
    assert episode_lines(1.0, 0.5, 0.5, 1.0, gait=gait)[-1].split() == ["SLIP", "42%"]
    gait["wheel_slip_share"] = math.nan  # unlimited grip: no flags, the reference cone's share
    gait["outside_friction_cone_share"] = 0.07
    assert episode_lines(1.0, 0.5, 0.5, 1.0, gait=gait)[-1].split() == ["SLIP", "7%"]
