"""``snake-eval --sliding-wheels STEPS``: one controller on the env and on wheels that slide.

The env's wheels keep their grip (the no-slip model with the traction limit); the sliding-wheel
reference (:mod:`snake_env.physics.sliding_reference`) lets a wheel past mu m g slide under Coulomb
friction. Both start from the first evaluation episode's reset state and run the same controller
for STEPS steps; a gait that needs more grip than its wheels have loses speed on the second.
"""

from __future__ import annotations

import numpy as np

from snake_env.train.evaluate import EvalError, first_line, make_env


def compare_on_sliding_wheels(env_id: str, env_kwargs: dict, act, reset, seed: int, steps: int,
                              slip_speed: float = 1e-3, env_wrapper=None) -> dict:
    """Speeds (m/s) of ``act`` over the first ``steps`` steps of the episode of ``seed`` on the env and on
    sliding wheels, the share of wheel-steps sliding and friction's mean power (W)."""
    from snake_env.physics.sliding_reference import SlidingSnake

    if env_wrapper:
        raise EvalError(f"--sliding-wheels runs plain-torque policies, not env_wrapper {env_wrapper!r}")
    env = make_env(env_id, env_kwargs, render=False)
    try:
        base = env.unwrapped
        if base.task.name != "forward":
            raise EvalError(f"--sliding-wheels runs the forward task, {env_id} is a {base.task.name} task")
        try:
            snake = SlidingSnake(base.config, slip_speed)
        except ValueError as exc:
            raise EvalError(f"--sliding-wheels on {env_id}: {first_line(exc)}") from None
        obs, _ = env.reset(seed=seed)
        q, u = base.state
        reset()
        env_speeds = []
        for _ in range(steps):
            obs, _, terminated, truncated, info = env.step(act(obs))
            env_speeds.append(float(info["x_velocity"]))
            if terminated or truncated:
                break
    finally:
        env.close()
    reset()
    obs = snake.reset(q, u)
    speeds, sliding, friction = [], [], 0.0
    for _ in range(len(env_speeds)):
        obs, info = snake.step(act(obs))
        speeds.append(info["x_velocity"])
        sliding.append(info["wheel_sliding"])
        friction += info["friction_work"]
    env_v, v = float(np.mean(env_speeds)), float(np.mean(speeds))
    return {
        "steps": len(speeds), "seed": seed, "wheel_friction": float(base.config.wheel_friction),
        "slip_speed": slip_speed, "env_wheel_model": base.config.wheel_model,
        "env_x_velocity": env_v, "sliding_x_velocity": v,
        "speed_ratio": v / env_v if env_v != 0.0 else float("nan"),
        "wheel_steps_sliding": float(np.mean(sliding)),
        "friction_power": -friction / (len(speeds) * base.config.dt),
    }


def print_comparison(result: dict) -> None:
    print(f"\nsliding wheels (mu {result['wheel_friction']:g}, Coulomb friction regularised over "
          f"{result['slip_speed'] * 1e3:g} mm/s), episode seed {result['seed']}, first {result['steps']} steps:")
    env = ("no-slip, traction limit" if result["env_wheel_model"] == "no_slip"
           else "sliding wheels, exact Coulomb, time-stepped")
    print(f"  v_x on the env ({env}): {result['env_x_velocity']:.3f} m/s")
    print(f"  v_x on the regularised reference: {result['sliding_x_velocity']:.3f} m/s "
          f"({result['speed_ratio']:.2f}x)")
    print(f"  wheel-steps sliding: {100 * result['wheel_steps_sliding']:.1f} %; friction power "
          f"{result['friction_power']:.3f} W")
