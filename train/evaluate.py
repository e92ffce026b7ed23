"""``snake-eval``: headless evaluation of a saved policy or of the serpenoid baseline.

Examples::

    snake-eval runs/Snake5-v2__ppo__s0__20260101-120000 --episodes 5 --json eval.json
    snake-eval runs/.../checkpoints/model_200000_steps.zip --plot cm.png --video snake.gif
    snake-eval --baseline serpenoid --env snake_env/Snake5-v2 --json serpenoid.json
    snake-eval --baseline los --env snake_env/SnakePath5-v2 --json los.json
    snake-eval --baseline steering --env snake_env/SnakeCommand5-v1
    snake-eval --baseline homing --env snake_env/SnakeReach5-v1
    snake-eval --onnx policy.onnx --episodes 5   # onnxruntime only: neither torch nor SB3 is imported
    snake-eval runs/multi_n_run --env snake_env/Snake20-v2   # a JointPolicy run on an n it was not trained on

The env id, env kwargs and VecNormalize statistics come from the run's
``config.yaml`` and the statistics file saved beside the model; the
statistics are applied with ``training=False, norm_reward=False`` and never
updated. Rendering uses ``rgb_array`` only, so no display is needed.
Metrics per episode: return, mean forward velocity (mean of
``info["x_velocity"]``, m/s, whole-snake CM), final distance from the
origin (m), x displacement (m), length (steps), and the task metrics of
:mod:`snake_env.train.task_metrics` (cost of transport for every task; success, goal
distance, cross-track or tracking errors by task).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from snake_env.train.config import first_line

EXIT_ERROR = 2
VIDEO_SUFFIXES = (".gif", ".mp4")


def shipped_baselines() -> dict[str, str]:
    """``--baseline`` name -> the shipped task it drives (each task class names its own baseline)."""
    from snake_env.tasks import TASKS

    return {cls.baseline_name: name for name, cls in TASKS.items() if cls.baseline_name}


class EvalError(ValueError):
    """A one-line CLI error."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="snake-eval", description="Evaluate a saved snake policy headlessly.")
    parser.add_argument("target", nargs="?", help="run directory or model .zip (omit with --baseline)")
    parser.add_argument("--baseline", metavar="NAME",
                        help="evaluate the env's task baseline instead of a policy: " +
                             "; ".join(f"{name} ({task} task)" for name, task in shipped_baselines().items()))
    parser.add_argument("--onnx", help="evaluate a policy exported by snake-export (onnxruntime only, no torch)")
    parser.add_argument("--env", dest="env_id", help="env id (required with --baseline; for a model it must match, "
                                                     "except for policy JointPolicy, which runs on any n)")
    parser.add_argument("--episodes", type=int, default=5, help="number of episodes (default 5)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--deterministic", dest="deterministic", action="store_true", default=True,
                      help="use the policy's mean action (default)")
    mode.add_argument("--stochastic", dest="deterministic", action="store_false", help="sample actions")
    parser.add_argument("--seed", type=int, default=0, help="seed of episode k is seed + k (default 0)")
    parser.add_argument("--max-steps", type=int, default=None, help="cap on steps per episode (default: the env's)")
    parser.add_argument("--video", help="write the first episode as PATH.gif or PATH.mp4, with a heads-up display "
                                        "(time, speed, distance, return) and a scale bar")
    parser.add_argument("--compare", metavar="serpenoid|RUN_DIR",
                        help="with --video: the first episode of this second controller (same env and seed) "
                             "side by side with the evaluated one")
    parser.add_argument("--no-hud", dest="hud", action="store_false", help="plain frames in --video")
    parser.add_argument("--plot", help="write the CM trajectories as a PNG")
    parser.add_argument("--json", dest="json_path", help="write the metrics as JSON")
    parser.add_argument("--env-kwarg", dest="env_kwargs", action="append", default=[], metavar="KEY=VALUE",
                        help="set an env kwarg (value read as YAML), e.g. path_type=circle; repeatable; "
                             "overrides the run's env_kwargs")
    parser.add_argument("--sliding-wheels", type=int, metavar="STEPS",
                        help="also run the first episode's first STEPS steps on wheels that slide under Coulomb "
                             "friction (snake_env.physics.sliding_reference), beside the env's: speed and share of "
                             "wheel-steps sliding (forward task, plain torques, finite wheel_friction)")
    parser.add_argument("--serpenoid-config", help="gait YAML for --baseline, whose controllers run the searched "
                                                   "gaits (default ./configs/serpenoid.yaml if it exists, else the "
                                                   "shipped one)")
    return parser


def make_env(env_id: str, env_kwargs: dict, render: bool, env_wrapper=None):
    import gymnasium as gym

    import snake_env  # noqa: F401
    from snake_env.wrappers import wrap_env

    try:
        return wrap_env(gym.make(env_id, render_mode="rgb_array" if render else None, **env_kwargs), env_wrapper)
    except (ValueError, TypeError, gym.error.Error) as exc:
        raise EvalError(f"cannot make env {env_id!r} with env_kwargs {env_kwargs}: {first_line(exc)}") from None


def wheel_forces(base, info: dict):
    """The wheels' lateral forces (N) of the step: the info's when the env reports them (``wheel_friction``
    given), else computed once by the env."""
    forces = info.get("wheel_lateral_force")
    return base.wheel_lateral_forces() if forces is None else forces


def run_episodes(env, act, reset_controller, episodes: int, seed: int, max_steps=None):
    """Roll out ``episodes`` episodes (seed + k); return (per-episode dicts, CM paths)."""
    from snake_env.train.task_metrics import EpisodeRecorder

    base = env.unwrapped
    results, paths = [], []
    for episode in range(episodes):
        obs, info = env.reset(seed=seed + episode)
        recorder = EpisodeRecorder(base.task.episode_metrics, base.dt, base.task.weight(base.config), info,
                                   wheel_load=base.config.wheel_load(), wheel_friction=base.config.wheel_friction)
        reset_controller()
        xy = [(info["x_position"], info["y_position"])]
        x0 = info["x_position"]
        total, speeds, steps = 0.0, [], 0
        while True:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            total += float(reward)
            speeds.append(float(info["x_velocity"]))
            recorder.add(info, base.joint_state(), wheel_forces(base, info))
            xy.append((info["x_position"], info["y_position"]))
            steps += 1
            if terminated or truncated or (max_steps is not None and steps >= max_steps):
                break
        results.append({
            "episode": episode,
            "seed": seed + episode,
            "return": total,
            "forward_velocity": float(np.mean(speeds)),
            "distance": float(info["distance_from_origin"]),
            "x_displacement": float(info["x_position"] - x0),
            "length": steps,
            "sim_failure": bool(info.get("sim_failure", False)),
            **{key: (None if isinstance(v, float) and not math.isfinite(v) else v)
               for key, v in recorder.metrics().items()},
        })
        paths.append(np.asarray(xy))
    return results, paths


def summarize(results: list[dict]) -> dict:
    returns = np.array([r["return"] for r in results])
    speeds = np.array([r["forward_velocity"] for r in results])
    distances = np.array([r["distance"] for r in results])
    return {
        "mean_return": float(returns.mean()),
        "std_return": float(returns.std()),
        "mean_forward_velocity": float(speeds.mean()),
        "std_forward_velocity": float(speeds.std()),
        "mean_distance": float(distances.mean()),
        "mean_length": float(np.mean([r["length"] for r in results])),
    }


def print_task_metrics(task: str, metrics: dict) -> None:
    units = {"success_rate": "", "mean_cost_of_transport": "", "mean_final_goal_distance": " m",
             "mean_cross_track_error": " m", "mean_path_speed": " m/s", "mean_speed_error": " m/s",
             "mean_yaw_rate_error": " rad/s", "mean_dominant_joint_frequency": " Hz", "max_peak_joint_rate": " rad/s",
             "mean_power": " W", "max_peak_power": " W", "mean_median_grip_demand": " m g",
             "max_peak_grip_demand": " m g"}
    parts = [f"{key} = {'n/a' if value is None else f'{value:.4g}'}{units.get(key, '')}" for key, value in metrics.items()]
    print(f"{task}: " + ", ".join(parts))


def _cell(value, width: int, spec: str) -> str:
    """A table cell: the number, or n/a (a metric without a value, e.g. a gait frequency of a short episode)."""
    return f"{'n/a':>{width}}" if value is None else f"{value:>{width}{spec}}"


def print_table(title: str, results: list[dict], summary: dict) -> None:
    print(title)
    print(f"{'episode':>7} {'seed':>6} {'return':>10} {'v_x (m/s)':>10} {'distance (m)':>12} {'steps':>6} "
          f"{'gait (Hz)':>9} {'max rate (rad/s)':>16} {'flips':>6}")
    for r in results:
        print(f"{r['episode']:>7} {r['seed']:>6} {r['return']:>10.3f} {r['forward_velocity']:>10.4f} "
              f"{r['distance']:>12.3f} {r['length']:>6} {_cell(r.get('dominant_joint_frequency'), 9, '.2f')} "
              f"{_cell(r.get('peak_joint_rate'), 16, '.1f')} {_cell(r.get('torque_sign_flip_share'), 6, '.0%')}")
    print(f"{'mean':>7} {'':>6} {summary['mean_return']:>10.3f} {summary['mean_forward_velocity']:>10.4f} "
          f"{summary['mean_distance']:>12.3f} {summary['mean_length']:>6.0f}")
    print(f"{'std':>7} {'':>6} {summary['std_return']:>10.3f} {summary['std_forward_velocity']:>10.4f}")


SPEED_WINDOW_S = 1.0  # the HUD's forward speed is the mean over the last second (the gait undulates at ~4 Hz)


class VideoWriter:
    """Append frames to PATH.gif (every other frame, real-time duration) or PATH.mp4
    (imageio's ffmpeg plugin, every frame); the file appears atomically on close."""

    def __init__(self, path: Path, fps: float):
        self.path = Path(path)
        self.fps = float(fps)
        self.count = 0  # frames offered
        self.written = 0

    def __enter__(self):
        import imageio.v2 as imageio

        from snake_env.train.atomic import atomic_path

        self._atomic = atomic_path(self.path, suffix=self.path.suffix)
        tmp = self._atomic.__enter__()
        try:
            if self.path.suffix == ".gif":
                self._writer = imageio.get_writer(tmp, mode="I", duration=2000.0 / self.fps, loop=0)
            else:
                self._writer = imageio.get_writer(tmp, format="FFMPEG", mode="I", fps=self.fps, macro_block_size=1)
        except (ImportError, ValueError, RuntimeError) as exc:
            self._atomic.__exit__(type(exc), exc, None)
            raise EvalError(f"writing {self.path.suffix} needs the imageio-ffmpeg package "
                            f"(pip install imageio-ffmpeg), or use a .gif path: {first_line(exc)}") from None
        return self

    def append(self, frame: np.ndarray) -> None:
        # every other frame keeps GIFs small; their frame duration keeps real time
        if self.path.suffix != ".gif" or self.count % 2 == 0:
            self._writer.append_data(np.ascontiguousarray(frame))
            self.written += 1
        self.count += 1

    def __exit__(self, exc_type, exc, tb):
        self._writer.close()
        if exc_type is None and self.written == 0:
            exc = EvalError("no frames were rendered")
            self._atomic.__exit__(EvalError, exc, None)
            raise exc
        return self._atomic.__exit__(exc_type, exc, tb)


def episode_frames(env, act, reset_controller, seed: int, max_steps=None, label=None, hud=True):
    """Yield the rgb frames of one episode (seed ``seed``), with the heads-up display:
    time, forward speed (mean over the last second), distance from the origin, return,
    the gait metrics of the episode so far, and a scale bar in metres. The camera follows the snake's centre of mass."""
    from snake_env.envs.hud import draw_hud, episode_lines
    from snake_env.train.gait_metrics import GaitRecorder

    obs, info = env.reset(seed=seed)
    reset_controller()
    dt = float(env.unwrapped.dt)
    window = max(1, int(round(SPEED_WINDOW_S / dt)))
    speeds, total, steps = [], 0.0, 0
    gait = GaitRecorder(dt, env.unwrapped.config.wheel_load(), env.unwrapped.config.wheel_friction)

    def decorate(frame):
        if not hud:
            return frame
        renderer = getattr(env.unwrapped, "_renderer", None)
        lines = episode_lines(steps * dt, float(np.mean(speeds[-window:])) if speeds else 0.0,
                              float(info["distance_from_origin"]), total, label, gait.metrics() if steps else None)
        return draw_hud(frame, lines, getattr(renderer, "scale", None))

    yield decorate(env.render())
    while True:
        obs, reward, terminated, truncated, info = env.step(act(obs))
        gait.add(env.unwrapped.joint_state(), info["actuator_power"], wheel_forces(env.unwrapped, info),
                 info.get("wheel_slip"))
        total += float(reward)
        speeds.append(float(info["x_velocity"]))
        steps += 1
        yield decorate(env.render())
        if terminated or truncated or (max_steps is not None and steps >= max_steps):
            return


def side_by_side(*streams):
    """Frames of several episodes next to each other, split by a dark 4-pixel column;
    a finished episode holds its last frame."""
    import itertools

    last = [None] * len(streams)
    for frames in itertools.zip_longest(*streams):
        last = [new if new is not None else old for new, old in zip(frames, last)]
        divider = np.full((last[0].shape[0], 4, 3), 40, np.uint8)
        parts = [last[0]]
        for frame in last[1:]:
            parts += [divider, frame]
        yield np.concatenate(parts, axis=1)


def write_video(frames, path: Path, fps: float) -> int:
    """Write an iterable of frames; return how many frames the file holds."""
    with VideoWriter(path, fps) as writer:
        for frame in frames:
            writer.append(frame)
    return writer.written


def check_outputs(args) -> None:
    if args.episodes < 1:
        raise EvalError(f"--episodes must be >= 1, got {args.episodes}")
    if args.sliding_wheels is not None and args.sliding_wheels < 1:
        raise EvalError(f"--sliding-wheels must be >= 1 steps, got {args.sliding_wheels}")
    if args.max_steps is not None and args.max_steps < 1:
        raise EvalError(f"--max-steps must be >= 1, got {args.max_steps}")
    if args.video and Path(args.video).suffix not in VIDEO_SUFFIXES:
        raise EvalError(f"--video must end with one of {list(VIDEO_SUFFIXES)}, got {args.video!r}")
    if args.video and Path(args.video).suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise EvalError("writing .mp4 needs the imageio-ffmpeg package (pip install imageio-ffmpeg); "
                            "or use a .gif path") from None
    if args.compare and not args.video:
        raise EvalError("--compare renders a side-by-side video; give --video PATH too")
    if args.plot and Path(args.plot).suffix != ".png":
        raise EvalError(f"--plot must be a .png path, got {args.plot!r}")
    given = [name for name, value in (("a run directory/model", args.target), ("--baseline", args.baseline),
                                      ("--onnx", args.onnx)) if value]
    if len(given) > 1:
        raise EvalError(f"give one of a run directory/model, --baseline or --onnx, not {' and '.join(given)}")
    if args.baseline and not args.env_id:
        raise EvalError(f"--baseline {args.baseline} needs --env ID")
    if not given:
        raise EvalError("give a run directory or model file (or --baseline serpenoid --env ID, or --onnx FILE)")
    if args.onnx and not args.deterministic:
        raise EvalError("--onnx policies are deterministic; drop --stochastic")


def policy_actor(args):
    """(env_id, env_kwargs, act(obs), reset(), description) of a saved policy."""
    from snake_env.agents.policy_loading import PolicyLoadError, load_policy, locate
    from snake_env.train.config import JOINT_POLICY, ConfigError, load_run_config
    from snake_env.train.joint_features import LayoutError, check_env_layout

    try:
        files = locate(args.target)
        config = {}
        if files.config is not None:
            config = load_run_config(files.config)
    except (PolicyLoadError, ConfigError) as exc:
        raise EvalError(str(exc)) from None
    env_id = args.env_id or config.get("env_id")
    if env_id is None:
        raise EvalError(f"no config.yaml beside {files.model}; pass --env ID")
    any_n = config.get("policy") == JOINT_POLICY  # the shared per-joint policy runs on snakes of any n
    if args.env_id and config.get("env_id") not in (None, args.env_id) and not any_n:
        raise EvalError(f"{files.model} was trained on {config['env_id']}, not {args.env_id} (only policy "
                        f"{JOINT_POLICY} runs on another env)")
    # --env-kwarg counts here too: n_links=16 on Snake-v2 rebuilds a JointPolicy for 16 links
    env_kwargs = {**dict(config.get("env_kwargs") or {}), **parse_env_kwargs(getattr(args, "env_kwargs", None))}
    env_wrapper = config.get("env_wrapper")
    env = make_env(env_id, env_kwargs, render=False, env_wrapper=env_wrapper)
    try:
        loaded = load_policy(files.model, env.observation_space, env.action_space, config)
        if any_n:
            check_env_layout(loaded.model.policy.layout, env, env_id)
    except (PolicyLoadError, LayoutError) as exc:
        raise EvalError(str(exc)) from None
    finally:
        env.close()

    def act(obs):
        return loaded.act(obs, deterministic=args.deterministic)

    stats = files.vecnormalize.name if files.vecnormalize else "none"
    title = (f"{loaded.algo.upper()} {files.model} on {env_id} "
             f"({'deterministic' if args.deterministic else 'stochastic'}; VecNormalize stats: {stats})")
    meta = {"algo": loaded.algo, "model": str(files.model), **({"env_wrapper": env_wrapper} if env_wrapper else {})}
    return env_id, env_kwargs, act, lambda: None, title, meta


def onnx_actor(args):
    """(env_id, env_kwargs, act(obs), reset(), description, meta) of an exported ONNX policy."""
    from snake_env.agents.onnx_policy import OnnxPolicy, OnnxPolicyError

    try:
        policy = OnnxPolicy(args.onnx)
    except OnnxPolicyError as exc:
        raise EvalError(str(exc)) from None
    if args.env_id and args.env_id != policy.env_id:
        raise EvalError(f"{args.onnx} was exported for {policy.env_id}, not {args.env_id}")
    env = make_env(policy.env_id, policy.env_kwargs, render=False, env_wrapper=policy.env_wrapper)
    try:
        policy.check_spaces(env.observation_space, env.action_space)
    except OnnxPolicyError as exc:
        raise EvalError(str(exc)) from None
    finally:
        env.close()
    algo = policy.metadata.get("algo", "onnx")
    title = f"{algo.upper()} {args.onnx} on {policy.env_id} (ONNX, onnxruntime; deterministic)"
    meta = {"algo": algo, "onnx": str(args.onnx), **({"env_wrapper": policy.env_wrapper} if policy.env_wrapper else {})}
    return policy.env_id, policy.env_kwargs, policy.act, lambda: None, title, meta


def baseline_actor(args):
    """(env_id, env_kwargs, act(obs), reset(), description, meta) of the env's task baseline
    (:meth:`snake_env.tasks.Task.make_baseline`, the gait file ``--serpenoid-config`` or the one
    :func:`snake_env.configfiles.config_path` resolves)."""
    from snake_env.envs.core import env_config

    env_kwargs = parse_env_kwargs(args.env_kwargs)
    try:
        task, config = env_config(args.env_id, env_kwargs)
    except ValueError as exc:
        raise EvalError(first_line(exc)) from None
    own = type(task).baseline_name
    if args.baseline != own:
        shipped = shipped_baselines()
        if args.baseline not in shipped:
            raise EvalError(f"--baseline must be one of {sorted({*shipped, *([own] if own else [])})}, "
                            f"got {args.baseline!r}")
        raise EvalError(f"--baseline {args.baseline} drives the {shipped[args.baseline]} task, {args.env_id} is a "
                        f"{task.name} task; use --baseline {own or '(none for this task)'}")
    try:
        controller = task.make_baseline(config, gaits=args.serpenoid_config)
    except ValueError as exc:
        raise EvalError(first_line(exc)) from None
    params = controller.params
    title = f"{args.baseline} baseline ({type(controller).__name__}, gait {params}) on {args.env_id}"
    return (args.env_id, env_kwargs, controller.act, controller.reset, title,
            {"algo": args.baseline, "params": params.to_dict()})


def parse_env_kwargs(items) -> dict:
    import yaml

    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise EvalError(f"--env-kwarg expects KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = yaml.safe_load(value) if value.strip() else None
        except yaml.YAMLError:
            out[key.strip()] = value
    return out


def compare_actor(args, env_id, env_kwargs):
    """(act, reset, label) of the ``--compare`` controller; it runs on the evaluated env, which must be the
    env it was trained or searched on (the same id and env kwargs, episode length aside)."""
    if args.compare == "serpenoid":
        other = argparse.Namespace(**{**vars(args), "baseline": "serpenoid", "target": None, "onnx": None,
                                      "env_id": env_id})
        other_env_id, other_kwargs, act, reset, _, _ = baseline_actor(other)
        label = "serpenoid"
    else:
        other = argparse.Namespace(**{**vars(args), "baseline": None, "target": args.compare, "onnx": None,
                                      "env_id": None})
        other_env_id, other_kwargs, act, reset, _, meta = policy_actor(other)
        label = f"{meta['algo']} {Path(args.compare).name}"
    physical = lambda kwargs: {k: v for k, v in kwargs.items() if k != "max_episode_steps"}  # noqa: E731
    if other_env_id != env_id or physical(other_kwargs) != physical(env_kwargs):
        raise EvalError(f"--compare {args.compare} runs on {other_env_id} with env_kwargs {other_kwargs}, "
                        f"not on {env_id} with {env_kwargs}")
    return act, reset, label


def record_video(args, env_id, env_kwargs, act, reset, algo, compare=None, env_wrapper=None) -> int:
    """Render episode ``args.seed`` (again) into ``args.video``; with ``compare``, side by side.
    ``env_wrapper``: the evaluated policy's opt-in wrappers (the compared controller runs unwrapped)."""
    envs = [make_env(env_id, env_kwargs, render=True, env_wrapper=env_wrapper if i == 0 else None)
            for i in range(2 if compare else 1)]
    try:
        fps = envs[0].metadata.get("render_fps", 25)
        streams = [episode_frames(envs[0], act, reset, args.seed, args.max_steps, label=algo if compare else None,
                                  hud=args.hud)]
        if compare:
            other_act, other_reset, label = compare
            streams.append(episode_frames(envs[1], other_act, other_reset, args.seed, args.max_steps, label=label,
                                          hud=args.hud))
        return write_video(side_by_side(*streams) if compare else streams[0], Path(args.video), fps)
    finally:
        for env in envs:
            env.close()


def evaluate(args) -> dict:
    check_outputs(args)
    if args.baseline:
        env_id, env_kwargs, act, reset, title, meta = baseline_actor(args)
    elif args.onnx:
        env_id, env_kwargs, act, reset, title, meta = onnx_actor(args)
    else:
        env_id, env_kwargs, act, reset, title, meta = policy_actor(args)
    env_kwargs = {**env_kwargs, **parse_env_kwargs(getattr(args, "env_kwargs", None))}
    if not args.deterministic:
        from stable_baselines3.common.utils import set_random_seed

        set_random_seed(args.seed)  # torch sampling of stochastic actions, reproducible
    compare = compare_actor(args, env_id, env_kwargs) if args.compare else None
    env = make_env(env_id, env_kwargs, render=False, env_wrapper=meta.get("env_wrapper"))
    try:
        results, paths = run_episodes(env, act, reset, args.episodes, args.seed, args.max_steps)
        task_class = type(env.unwrapped.task)
    finally:
        env.close()
    from snake_env.train.gait_metrics import summarize_gait
    from snake_env.train.task_metrics import summarize_task

    summary = summarize(results)
    task_summary = summarize_task(task_class.episode_metrics, results)
    gait_summary = summarize_gait(results)
    task = task_class.name
    print_table(title, results, summary)
    print_task_metrics(f"task {task}", task_summary)
    print_task_metrics("gait", gait_summary)
    report = {"env_id": env_id, "env_kwargs": env_kwargs, **meta, "deterministic": args.deterministic,
              "seed": args.seed, "n_episodes": args.episodes, **summary, "task": task, **task_summary, **gait_summary,
              "episodes": results}
    if args.sliding_wheels:
        from snake_env.train.sliding_check import compare_on_sliding_wheels, print_comparison

        report["sliding_wheels"] = compare_on_sliding_wheels(env_id, env_kwargs, act, reset, args.seed,
                                                             args.sliding_wheels,
                                                             env_wrapper=meta.get("env_wrapper"))
        print_comparison(report["sliding_wheels"])
    if args.json_path:
        from snake_env.train.atomic import atomic_write_text

        atomic_write_text(Path(args.json_path), json.dumps(report, indent=2, allow_nan=False) + "\n")
        print(f"metrics written to {args.json_path}")
    if args.plot:
        from snake_env.train.plots import plot_trajectories

        plot_trajectories(paths, Path(args.plot), f"CM trajectories: {meta['algo']} on {env_id}")
        print(f"trajectories plotted to {args.plot}")
    if args.video:
        count = record_video(args, env_id, env_kwargs, act, reset, meta["algo"], compare, meta.get("env_wrapper"))
        print(f"video written to {args.video} ({count} frames)")
    if not all(math.isfinite(v) for v in summary.values()):
        raise EvalError("evaluation produced non-finite metrics")
    return report


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        evaluate(args)
    except EvalError as exc:
        parser.exit(EXIT_ERROR, f"snake-eval: error: {exc}\n")
    except KeyboardInterrupt:
        parser.exit(130, "snake-eval: interrupted\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
