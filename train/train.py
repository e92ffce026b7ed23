"""``snake-train``: train a PPO or SAC policy on a snake env (SB3), RL Zoo style.

Examples::

    snake-train --algo ppo --env snake_env/Snake5-v2
    snake-train --algo sac --env snake_env/Snake3-v2 --set learning_rate=1e-3 --total-timesteps 50000
    snake-train --resume runs/Snake5-v2__ppo__s0__20260101-120000

The run directory holds ``config.yaml`` (the one merged config), ``model.zip``
and ``vecnormalize.pkl``, ``checkpoints/`` (each model with its statistics),
``best_model/`` (EvalCallback), ``logs/segment_<k>/`` (CSV + TensorBoard; a
resumed run adds a segment) and ``learning_curve.png``. Ctrl-C saves the
model and statistics (and a checkpoint) before exiting.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from snake_env.train import config as cfg

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
PROGRESS_MODES = ("auto", "bar", "lines", "none")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="snake-train",
        description="Train a PPO/SAC locomotion policy on a snake env (Stable-Baselines3, RL Zoo conventions).",
    )
    parser.add_argument("--algo", help=f"algorithm, one of {list(cfg.ALGOS)}")
    parser.add_argument("--env", dest="env_id", help="gymnasium env id, e.g. snake_env/Snake5-v2")
    parser.add_argument("--config", help="hyperparameter YAML keyed by env id (default ./configs/<algo>.yaml if it "
                                                          "exists, else the one shipped with snake_env)")
    parser.add_argument("--total-timesteps", type=int, help="environment steps to train (overrides n_timesteps)")
    parser.add_argument("--seed", type=int, help="random seed (default 0)")
    parser.add_argument("--n-envs", type=int, help="number of parallel envs (overrides n_envs)")
    parser.add_argument("--run-dir", help="run directory (default runs/<env>__<algo>__s<seed>__<time>/)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override a config key; dotted keys reach into env_kwargs/policy_kwargs; repeatable")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue a run from its newest checkpoint")
    parser.add_argument("--init-from", metavar="RUN_DIR|MODEL.zip",
                        help="start from another run's policy weights (fine-tuning, e.g. a JointPolicy trained "
                             "on other sizes); the policy must have the same parameter shapes")
    parser.add_argument("--progress", choices=PROGRESS_MODES, default="auto",
                        help="auto (default): a progress bar on a terminal, a line every 10%% or minute otherwise; "
                             "bar; lines; none")
    parser.add_argument("--no-progress-bar", action="store_true", help="no progress output (same as --progress none)")
    parser.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (0, 1 or 2)")
    return parser


def default_run_dir(config: dict) -> Path:
    env_name = config["env_id"].split("/")[-1].replace(":", "_")
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{env_name}__{config['algo']}__s{config['seed']}__{stamp}"


def prepare(args) -> tuple[dict, Path, bool]:
    """(config, run_dir, resuming) from the CLI, merging the config once."""
    if args.resume:
        run_dir = Path(args.resume)
        conflicting = [flag for flag, value in (("--algo", args.algo), ("--env", args.env_id),
                                                 ("--config", args.config), ("--seed", args.seed),
                                                 ("--n-envs", args.n_envs), ("--run-dir", args.run_dir),
                                                 ("--set", args.overrides), ("--init-from", args.init_from))
                       if value]
        if conflicting:
            raise cfg.ConfigError(f"--resume continues a run with its saved config.yaml; do not combine it with "
                                  f"{', '.join(conflicting)} (only --total-timesteps may change)")
        if not (run_dir / "config.yaml").is_file():
            raise cfg.ConfigError(f"--resume: {run_dir / 'config.yaml'} not found")
        config = cfg.load_run_config(run_dir / "config.yaml")
        if args.total_timesteps is not None:
            config["n_timesteps"] = args.total_timesteps
            config = cfg.validate(config)
        return config, run_dir, True
    if not args.algo or not args.env_id:
        raise cfg.ConfigError(f"--algo {{{','.join(cfg.ALGOS)}}} and --env ID are required (or --resume RUN_DIR)")
    cfg.check_algo(args.algo)
    config = cfg.build_config(args.algo, args.env_id, args.config, args.overrides, seed=args.seed,
                              n_timesteps=args.total_timesteps, n_envs=args.n_envs)
    if args.init_from is not None:
        config["init_from"] = str(cfg.init_weights_path(args.init_from))
        config = cfg.validate(config)
    run_dir = Path(args.run_dir) if args.run_dir else default_run_dir(config)
    if (run_dir / "model.zip").exists() or (run_dir / "checkpoints").exists():
        raise cfg.ConfigError(f"run directory {run_dir} already holds a run; use --resume {run_dir} or another --run-dir")
    return config, run_dir, False


def build_model(config: dict, venv, verbose: int):
    algo_cls = cfg.algo_class(config["algo"])
    try:
        return algo_cls(cfg.policy_for(config, venv.observation_space), venv, seed=config["seed"], device="cpu", verbose=verbose,
                        policy_kwargs=cfg.torch_policy_kwargs(config), **cfg.algo_kwargs(config))
    except (TypeError, ValueError, AssertionError) as exc:
        raise cfg.ConfigError(f"invalid {config['algo']} hyperparameters: {cfg.first_line(exc)}") from None


def load_initial_weights(model, init_from) -> None:
    """The policy (and optimizer) weights of another run's model into ``model`` (SB3's set_parameters, exact
    match); a shape or key mismatch is a one-line ConfigError. Normalization statistics are not carried
    over: the run gathers its own."""
    path = cfg.init_weights_path(init_from)
    try:
        model.set_parameters(str(path), exact_match=True, device="cpu")
    except (RuntimeError, KeyError, ValueError) as exc:
        raise cfg.ConfigError(f"init_from {path}: its weights do not fit this run's policy "
                              f"({cfg.first_line(exc)})") from None
    print(f"initialized the policy from {path}")


def next_segment(log_dir: Path) -> Path:
    existing = [int(p.name.split("_")[1]) for p in log_dir.glob("segment_*") if p.name.split("_")[1].isdigit()]
    return log_dir / f"segment_{max(existing, default=-1) + 1}"


_stopping = False  # an interrupt has been raised: the run is saving what it made


def _interrupt(signum, frame):
    """The first Ctrl-C (SIGINT) or SIGTERM ends training with KeyboardInterrupt, held until a save in
    progress ends (:func:`snake_env.train.atomic.defer_interrupt`); any further one while the run saves
    its model and checkpoint is ignored, so the save is never cut short."""
    from snake_env.train import atomic

    global _stopping
    if _stopping:
        print("snake_env: interrupted; saving what the run made, please wait", file=sys.stderr, flush=True)
        return
    _stopping = True
    if not atomic.defer_interrupt(signum):
        raise KeyboardInterrupt(f"signal {signum}")


def install_interrupt_handlers() -> None:
    """Ctrl-C (SIGINT) and SIGTERM both end training through KeyboardInterrupt,
    which saves the model (:func:`_interrupt`). SIGINT is set explicitly because a process started
    in the background of a non-interactive shell inherits it ignored."""
    import signal
    import threading

    global _stopping
    if threading.current_thread() is threading.main_thread():
        _stopping = False
        signal.signal(signal.SIGINT, _interrupt)
        signal.signal(signal.SIGTERM, _interrupt)


def progress_mode(requested: str) -> str:
    """``auto``: SB3's redrawn bar on a terminal, plain log lines otherwise."""
    from snake_env.train.progress import stdout_is_terminal

    if requested == "auto":
        return "bar" if stdout_is_terminal() else "lines"
    return requested


def next_steps_hint(run_dir: Path) -> str:
    """The commands that evaluate, render and export a finished run."""
    import shlex

    try:
        import imageio_ffmpeg  # noqa: F401
        video = "policy.mp4"
    except ImportError:
        video = "policy.gif"
    d = shlex.quote(str(run_dir))
    q = lambda name: shlex.quote(str(run_dir / name))  # noqa: E731
    return (f"evaluate and render: snake-eval {d} --episodes 10 --json {q('eval.json')} "
            f"--plot {q('trajectories.png')} --video {q(video)}\n"
            f"export to ONNX:      snake-export {d} --out {q('policy.onnx')}")


def run(config: dict, run_dir: Path, resuming: bool, progress_bar=True, verbose: int = 0) -> int:
    """Train (or resume) one run; ``progress_bar``: True/"auto", "bar", "lines", False/"none"."""
    import torch
    from stable_baselines3.common.callbacks import CallbackList, EvalCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from snake_env.train import callbacks as cb
    from snake_env.train.atomic import atomic_path
    from snake_env.train.envs import make_vec_env, wrap_normalize
    from snake_env.train.plots import plot_learning_curve

    install_interrupt_handlers()
    torch.set_num_threads(config["torch_threads"])
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_dir = run_dir / "checkpoints"
    best_dir = run_dir / "best_model"
    log_dir = run_dir / "logs"
    n_envs = config["n_envs"]

    start = None
    if resuming:
        start = cb.latest_checkpoint(checkpoint_dir)
        if start is None:
            raise cfg.ConfigError(f"--resume: no checkpoint (checkpoints/model_<steps>_steps.zip) in {run_dir}")
    env_seed = config["seed"] + (start[0] if start else 0)
    venv = make_vec_env(config, n_envs, env_seed)
    # at least one eval env per size of a multi-n run
    eval_envs = max(min(config["n_eval_episodes"], 8), len(config.get("n_links_set") or ()))
    eval_env = make_vec_env(config, eval_envs, config["seed"] + 10_000)
    eval_env = wrap_normalize(eval_env, config, training=False)

    if start is None:
        cfg.save_config(config, run_dir / "config.yaml")
        venv = wrap_normalize(venv, config, training=True)
        model = build_model(config, venv, verbose)
        if config["init_from"] is not None:
            load_initial_weights(model, config["init_from"])
    else:
        steps, model_path = start
        stats_path = cb.checkpoint_paths(checkpoint_dir, steps)["vecnormalize"]
        if cfg.normalize_options(config["normalize"], config.get("gamma")) is not None:
            if not stats_path.is_file():
                raise cfg.ConfigError(f"--resume: {model_path.name} has no VecNormalize statistics ({stats_path.name})")
            venv = VecNormalize.load(str(stats_path), venv)
            venv.training = True
        algo_cls = cfg.algo_class(config["algo"])
        model = algo_cls.load(model_path, env=venv, device="cpu", verbose=verbose)
        replay = checkpoint_dir / "replay_buffer.pkl"
        if hasattr(model, "load_replay_buffer") and replay.is_file():
            model.load_replay_buffer(replay)
        print(f"resuming {run_dir} from {model_path.name} ({model.num_timesteps} steps)")

    import gymnasium as gym

    from snake_env.train.exploration import apply_exploration

    spec = gym.spec(config["env_id"])
    apply_exploration(model, config, seq_len=spec.max_episode_steps or 1000)  # not saved with the model: each start
    segment = next_segment(log_dir)
    model.set_logger(configure(str(segment), ["csv", "tensorboard"]))
    eval_freq = max(1, config["eval_freq"] // n_envs)
    callbacks = CallbackList([
        cb.CheckpointWithStats(config["checkpoint_freq"], checkpoint_dir, verbose=verbose),
        EvalCallback(eval_env, n_eval_episodes=config["n_eval_episodes"], eval_freq=eval_freq,
                     deterministic=True, log_path=str(run_dir / "eval"), best_model_save_path=None,
                     callback_on_new_best=cb.SaveBestWithStats(best_dir), verbose=verbose),
        *cfg.make_callbacks(config),
    ])
    mode = progress_mode({True: "auto", False: "none"}.get(progress_bar, progress_bar))
    if mode == "lines":
        from snake_env.train.progress import LogProgress

        callbacks.callbacks.append(LogProgress(config["n_timesteps"]))  # initialized by learn() with the others
    remaining = config["n_timesteps"] - model.num_timesteps
    interrupted = False
    started = time.perf_counter()
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=callbacks, progress_bar=mode == "bar",
                        reset_num_timesteps=start is None, tb_log_name="tb")
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - started
    # the final model and its statistics; a checkpoint too, so --resume starts here
    cb.save_checkpoint(model, checkpoint_dir)
    cb.save_snapshot(model, run_dir / "model.zip", run_dir / "vecnormalize.pkl")
    if cb.vecnormalize_of(model) is None:
        (run_dir / "vecnormalize.pkl").unlink(missing_ok=True)
    title = f"{config['algo'].upper()} on {config['env_id']} (seed {config['seed']})"
    plot_learning_curve(log_dir, run_dir / "learning_curve.png", title)
    with atomic_path(run_dir / "wall_time.txt") as tmp:
        previous = 0.0
        if (run_dir / "wall_time.txt").is_file():
            try:
                previous = float((run_dir / "wall_time.txt").read_text().split()[0])
            except (ValueError, IndexError):
                previous = 0.0
        tmp.write_text(f"{previous + wall:.1f} s of training wall time, {model.num_timesteps} timesteps\n")
    venv.close()
    eval_env.close()
    state = "interrupted" if interrupted else "finished"
    print(f"{state} after {model.num_timesteps} timesteps ({wall:.0f} s); model saved to {run_dir / 'model.zip'}")
    print(next_steps_hint(run_dir))
    return EXIT_INTERRUPTED if interrupted else 0


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        config, run_dir, resuming = prepare(args)
        return run(config, run_dir, resuming, progress_bar="none" if args.no_progress_bar else args.progress,
                   verbose=args.verbose)
    except cfg.ConfigError as exc:
        parser.exit(EXIT_USAGE, f"snake-train: error: {exc}\n")
    except KeyboardInterrupt:
        # Ctrl-C before training started: nothing to save
        parser.exit(EXIT_INTERRUPTED, "snake-train: interrupted before training started\n")


if __name__ == "__main__":
    sys.exit(main())
