"""``snake-tune``: hyperparameter search for snake-train on Optuna.

Examples::

    snake-tune --algo ppo --env snake_env/Snake5-v2 --n-trials 30 --n-timesteps 150000 --out tuning/snake5_ppo
    # many workers on one study: the same command in N processes or on N machines
    snake-tune --algo ppo --env snake_env/Snake5-v2 --n-trials 10 --n-timesteps 150000 --out tuning/w1 \\
        --storage postgresql+psycopg://snake@dbhost:5432/optuna

A trial is one snake-train run with sampled hyperparameters
(:mod:`snake_env.train.tune_space`), evaluated ``--n-evaluations`` times on the
deterministic policy's mean forward speed and reported to Optuna, whose pruner
may stop it early (:mod:`snake_env.train.tune_objective`). The study lives in an
SQLAlchemy storage: by default ``DIR/study.db`` (SQLite, embedded), or any URL
Optuna's RDBStorage accepts; re-running a command resumes its study.
Heartbeats let the next worker to start fail the running trials of a killed one.
``--n-trials`` counts the trials of this process (Optuna's ``optimize``).

Writes ``DIR/best_config.yaml`` (configs/<algo>.yaml format, for
``snake-train --config``), ``DIR/study.csv`` and the optimization-history and
parameter-importance PNGs (:mod:`snake_env.train.tune_report`).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

from snake_env.train import config as cfg

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
SAMPLERS = ("tpe", "cmaes", "random")
PRUNERS = ("median", "hyperband", "none")
TPE_STARTUP_TRIALS = 10  # random trials before TPE models the space (RL Zoo's default)
MEDIAN_STARTUP_TRIALS = 5  # completed trials before the median pruner prunes (RL Zoo's default)


class UsageError(ValueError):
    """A bad argument; one line naming it and the allowed values."""


class OneLineParser(argparse.ArgumentParser):
    """argparse's own errors (a non-integer count, a missing value) as one line and exit 2."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="snake-tune",
        description="Hyperparameter search for snake-train (PPO/SAC) on Optuna; many workers may share a study.")
    parser.add_argument("--algo", metavar="{ppo,sac}", help=f"algorithm, one of {list(cfg.ALGOS)}")
    parser.add_argument("--env", metavar="ID", dest="env_id", help="registered env id, e.g. snake_env/Snake5-v2")
    parser.add_argument("--n-trials", metavar="N", type=int, help="trials this process runs (they add to the study)")
    parser.add_argument("--n-timesteps", metavar="T", type=int, help="training steps per trial (summed over envs)")
    parser.add_argument("--n-envs", metavar="K", type=int, help="parallel envs per trial (default: the config entry's n_envs)")
    parser.add_argument("--sampler", metavar="{tpe,cmaes,random}", default="tpe", help=f"Optuna sampler, one of {list(SAMPLERS)} (default tpe)")
    parser.add_argument("--pruner", metavar="{median,hyperband,none}", default="median", help=f"Optuna pruner, one of {list(PRUNERS)} (default median)")
    parser.add_argument("--n-evaluations", metavar="E", type=int, default=5,
                        help="evaluations (reports to the pruner) per trial, evenly spaced (default 5)")
    parser.add_argument("--storage", metavar="URL", help="SQLAlchemy URL of the study (default sqlite:///DIR/study.db), "
                                          "e.g. postgresql+psycopg://user@host:5432/db")
    parser.add_argument("--study-name", metavar="NAME", help="study name (default <algo>-<env name>, e.g. ppo-Snake5-v2)")
    parser.add_argument("--seed", metavar="S", type=int, help="training seed of every trial (default the entry's or 0); "
                                                  "also seeds the sampler (give workers of one study different seeds)")
    parser.add_argument("--timeout", metavar="SECONDS", type=float, help="stop starting trials after this many seconds")
    parser.add_argument("--out", metavar="DIR", help="output directory: best_config.yaml, study.csv, plots (and study.db)")
    parser.add_argument("--config", metavar="YAML", help="YAML keyed by env id whose entry every trial starts from "
                                         "(default configs/<algo>.yaml; an env without an entry starts from defaults)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="fix a config key (as in snake-train); a fixed key is not searched; repeatable")
    parser.add_argument("--baseline", action="store_true",
                        help="search nothing: every trial runs the config entry as is (a reference value)")
    parser.add_argument("--heartbeat-interval", metavar="SECONDS", type=int, default=60,
                        help="seconds between a running trial's heartbeats; a trial silent for twice this is "
                             "failed by the next worker to start a trial (default 60)")
    parser.add_argument("--verbose", metavar="{0,1}", type=int, default=0, help="0: a line per trial; 1: also Optuna's log")
    return parser


# ---------------------------------------------------------------- validation (writes nothing)
def check_positive(name: str, value, required: bool = True, kind=int) -> None:
    if value is None:
        if required:
            raise UsageError(f"{name} is required (a positive {'integer' if kind is int else 'number'})")
        return
    if not (value > 0 and math.isfinite(value)):
        raise UsageError(f"{name} must be a positive {'integer' if kind is int else 'number'}, got {value!r}")


def check_env_id(env_id) -> None:
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)

    known = sorted(k for k in gym.registry if k.startswith("snake_env/"))
    if not env_id:
        raise UsageError(f"--env is required; registered snake envs: {known}")
    try:
        gym.spec(env_id)
    except gym.error.Error:
        raise UsageError(f"--env {env_id!r} is not a registered env id; registered snake envs: {known}") from None


def base_config(args) -> dict:
    """The validated config every trial starts from: the YAML entry (if any),
    ``--set`` overrides, then the budget, env count and seed."""
    path = Path(args.config) if args.config else cfg.default_config_path(args.algo)
    if args.config or path.is_file():
        data = cfg.read_yaml(path)
        entry = cfg.hyperparams_for(args.env_id, args.algo, path) if (args.config or args.env_id in data) else {}
    else:
        entry = {}
    entry = cfg.apply_overrides(entry, args.overrides)
    for key in cfg.RUN_KEYS:
        if key in entry and key != "seed":
            raise cfg.ConfigError(f"{key} cannot be set in a config entry; use --{key.replace('_', '-')}")
    entry.update(algo=args.algo, env_id=args.env_id, n_timesteps=args.n_timesteps)
    if args.seed is not None:
        entry["seed"] = args.seed
    if args.n_envs is not None:
        entry["n_envs"] = args.n_envs
    return cfg.validate(entry)


def storage_url(args, out: Path) -> str:
    return args.storage if args.storage else f"sqlite:///{(out / 'study.db').resolve()}"


def check_storage(url: str) -> None:
    """Parse the URL, load its driver and connect once; an SQLite file that does
    not exist yet is not created here (only its directory is checked)."""
    import sqlalchemy
    from sqlalchemy.engine import make_url
    from sqlalchemy.pool import NullPool

    try:
        parsed = make_url(url)
    except sqlalchemy.exc.ArgumentError:
        raise UsageError(f"--storage {url!r} is not an SQLAlchemy URL; expected e.g. sqlite:///path/study.db or "
                         "postgresql+psycopg://user@host:5432/db") from None
    shown = parsed.render_as_string(hide_password=True)
    try:
        parsed.get_dialect()
    except (sqlalchemy.exc.NoSuchModuleError, ImportError) as exc:
        hint = ' (pip install -e ".[postgres]")' if parsed.get_backend_name() == "postgresql" else ""
        raise UsageError(f"--storage {shown}: no database driver: {_first_line(exc)}{hint}") from None
    if parsed.get_backend_name() == "sqlite":
        database = parsed.database or ""
        if database in ("", ":memory:"):
            raise UsageError("--storage: an in-memory SQLite database cannot hold a study; give a file, "
                             "e.g. sqlite:///tuning/study.db")
        path = Path(database)
        if not path.exists():
            if not path.parent.is_dir():
                raise UsageError(f"--storage {shown}: directory {path.parent} does not exist")
            return
    connect_args = {"connect_timeout": 10} if parsed.get_backend_name() == "postgresql" else {}
    engine = sqlalchemy.create_engine(parsed, poolclass=NullPool, connect_args=connect_args)
    try:
        with engine.connect():
            pass
    except Exception as exc:  # any driver's connection error: refused, auth, unknown database, timeout
        raise UsageError(f"--storage {shown}: cannot connect: {_first_line(exc)}") from None
    finally:
        engine.dispose()


def _first_line(exc: BaseException) -> str:
    """:func:`snake_env.train.config.first_line` of a database error's driver exception (``orig``) if any."""
    return cfg.first_line(getattr(exc, "orig", None) or exc)


def check_args(args) -> tuple[dict, Path, str]:
    """Validate every argument before anything is created or written."""
    if args.algo not in cfg.ALGOS:
        raise UsageError(f"--algo must be one of {list(cfg.ALGOS)}, got {args.algo!r}")
    if args.sampler not in SAMPLERS:
        raise UsageError(f"--sampler must be one of {list(SAMPLERS)}, got {args.sampler!r}")
    if args.pruner not in PRUNERS:
        raise UsageError(f"--pruner must be one of {list(PRUNERS)}, got {args.pruner!r}")
    check_positive("--n-trials", args.n_trials)
    check_positive("--n-timesteps", args.n_timesteps)
    check_positive("--n-envs", args.n_envs, required=False)
    check_positive("--n-evaluations", args.n_evaluations)
    check_positive("--timeout", args.timeout, required=False, kind=float)
    check_positive("--heartbeat-interval", args.heartbeat_interval)
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed must be a non-negative integer, got {args.seed}")
    if args.study_name is not None and not args.study_name.strip():
        raise UsageError("--study-name must not be empty")
    if not args.out:
        raise UsageError("--out DIR is required (best_config.yaml, study.csv, plots; study.db by default)")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory")
    check_env_id(args.env_id)
    try:
        base = base_config(args)
    except cfg.ConfigError as exc:
        raise UsageError(str(exc)) from None
    if args.n_evaluations > base["n_timesteps"]:
        raise UsageError(f"--n-evaluations ({args.n_evaluations}) must not exceed --n-timesteps ({base['n_timesteps']})")
    url = storage_url(args, out)
    if args.storage:
        check_storage(url)
    return base, out, url


# ---------------------------------------------------------------- Optuna objects
def make_sampler(name: str, seed):
    import optuna

    if name == "tpe":
        # constant_liar: parallel workers do not all sample next to the same running trial
        return optuna.samplers.TPESampler(n_startup_trials=TPE_STARTUP_TRIALS, multivariate=True,
                                          constant_liar=True, seed=seed)
    if name == "cmaes":
        # categorical parameters are sampled by CMA-ES's independent (random) sampler
        return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    return optuna.samplers.RandomSampler(seed=seed)


def make_pruner(name: str, n_evaluations: int):
    import optuna

    if name == "median":
        return optuna.pruners.MedianPruner(n_startup_trials=MEDIAN_STARTUP_TRIALS,
                                           n_warmup_steps=n_evaluations // 3)
    if name == "hyperband":
        return optuna.pruners.HyperbandPruner(min_resource=1, max_resource=n_evaluations, reduction_factor=3)
    return optuna.pruners.NopPruner()


def make_storage(url: str, heartbeat_interval: int, attempts: int = 5):
    """Optuna's RDBStorage with heartbeats. Workers started together on an empty
    database race to create Optuna's tables; the loser's CREATE fails on the
    winner's objects, and a retry finds the schema in place."""
    import random

    import optuna
    import sqlalchemy

    engine_kwargs = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {"pool_pre_ping": True}
    for attempt in range(attempts):
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs, heartbeat_interval=heartbeat_interval,
                                              grace_period=2 * heartbeat_interval)
        except (sqlalchemy.exc.IntegrityError, sqlalchemy.exc.ProgrammingError, sqlalchemy.exc.OperationalError):
            if attempt == attempts - 1:
                raise
            time.sleep(0.5 + random.random())


STUDY_ATTRS = ("algo", "env_id", "n_timesteps")


def open_study(args, base: dict, url: str, study_name: str):
    """Create the study or load it (resume); a study made for another algo,
    env or budget is refused before anything is written to it."""
    import optuna

    storage = make_storage(url, args.heartbeat_interval)
    try:
        existing = optuna.load_study(study_name=study_name, storage=storage)
    except KeyError:
        existing = None
    if existing is not None:
        for key in STUDY_ATTRS:
            stored = existing.user_attrs.get(key)
            if stored is not None and stored != base[key]:
                flag = {"env_id": "--env", "n_timesteps": "--n-timesteps"}.get(key, f"--{key}")
                raise UsageError(f"{flag} {base[key]!r} differs from the {stored!r} that study {study_name!r} was "
                                 "created with; use the same value or another --study-name")
    n_before = len(existing.get_trials(deepcopy=False)) if existing is not None else 0
    seed = None if args.seed is None else args.seed + n_before
    study = optuna.create_study(study_name=study_name, storage=storage, direction="maximize",
                                sampler=make_sampler(args.sampler, seed),
                                pruner=make_pruner(args.pruner, args.n_evaluations), load_if_exists=True)
    if existing is None:
        for key in STUDY_ATTRS:
            study.set_user_attr(key, base[key])
    return study


def fail_stale(study) -> list[int]:
    """Fail the running trials whose worker stopped beating (Optuna's
    ``fail_stale_trials``); returns their numbers."""
    import optuna
    from optuna.trial import TrialState

    running = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))}
    if not running:
        return []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        optuna.storages.fail_stale_trials(study)
    failed = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.FAIL,))}
    return sorted(running & failed)


# ---------------------------------------------------------------- progress
def trial_line(study, trial) -> str:
    from optuna.trial import TrialState

    value = f"{trial.value:.4f} m/s" if trial.value is not None else "-"
    if trial.state == TrialState.PRUNED and trial.intermediate_values:
        step = max(trial.intermediate_values)
        value = f"{trial.intermediate_values[step]:.4f} m/s at evaluation {step}"
    try:
        best = f"best {study.best_value:.4f} m/s (trial {study.best_trial.number})"
    except ValueError:
        best = "best -"
    seconds = trial.duration.total_seconds() if trial.duration else 0.0
    line = f"trial {trial.number:>4} {trial.state.name:<8} {value:<32} {best}  {seconds:.0f} s"
    reason = trial.user_attrs.get("fail_reason")
    if trial.state == TrialState.FAIL and reason:
        line += f"  ({reason})"
    return line


class Progress:
    """Optuna ``optimize`` callback: one line per finished trial of this process."""

    def __init__(self):
        self.finished = []

    def __call__(self, study, trial) -> None:
        self.finished.append(trial.state.name)
        print(trial_line(study, trial), flush=True)


def with_fail_reason(objective):
    """A crashing trial is failed (Optuna's ``catch``), its first error line kept as a user attribute."""
    import optuna

    def run(trial):
        try:
            return objective(trial)
        except optuna.TrialPruned:
            raise
        except Exception as exc:
            trial.set_user_attr("fail_reason", f"{type(exc).__name__}: {_first_line(exc)}")
            raise

    return run


# ---------------------------------------------------------------- main
def run(args, base: dict, out: Path, url: str) -> int:
    import optuna

    from snake_env.train import tune_report, tune_space
    from snake_env.train.tune_objective import Objective
    from snake_env.train.train import install_interrupt_handlers

    optuna.logging.set_verbosity(optuna.logging.INFO if args.verbose else optuna.logging.ERROR)
    # heartbeats and matplotlib plots are marked experimental in Optuna; they are used as documented
    warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
    install_interrupt_handlers()
    fixed = {".".join(cfg.parse_override(text)[0]) for text in args.overrides}
    dimensions = () if args.baseline else tune_space.searched(args.algo, fixed)
    study_name = args.study_name or f"{args.algo}-{args.env_id.split('/')[-1]}"
    out.mkdir(parents=True, exist_ok=True)
    study = open_study(args, base, url, study_name)
    shown_url = url if not args.storage else _hide_password(url)
    n_before = len(study.get_trials(deepcopy=False))
    print(f"study {study_name!r} in {shown_url}: {n_before} trials so far; {args.n_trials} more here, "
          f"{args.n_timesteps} steps each, {args.n_evaluations} evaluations, sampler {args.sampler}, "
          f"pruner {args.pruner}; searching {[d.param for d in dimensions]}", flush=True)
    stale = fail_stale(study)
    if stale:
        print(f"failed stale trial(s) {stale}: their worker stopped sending heartbeats", flush=True)
    progress = Progress()
    started = time.perf_counter()
    interrupted = False
    try:
        study.optimize(with_fail_reason(Objective(base, dimensions, args.n_evaluations)), n_trials=args.n_trials,
                       timeout=args.timeout, catch=(Exception,), callbacks=[progress], gc_after_trial=True)
    except KeyboardInterrupt:
        interrupted = True  # Optuna has marked the running trial failed
    wall = time.perf_counter() - started
    counts = tune_report.state_counts(study)
    print(f"{'interrupted' if interrupted else 'finished'}: {len(progress.finished)} trials here in {wall:.0f} s; "
          f"study {study_name!r} has {sum(counts.values())} trials "
          f"({', '.join(f'{n} {state}' for state, n in sorted(counts.items()))})", flush=True)
    if tune_report.completed(study):
        best = study.best_trial
        print(f"best: trial {best.number}, {best.value:.4f} m/s, params {best.params}", flush=True)
    else:
        print("no completed trial yet: best_config.yaml not written", flush=True)
    for line in tune_report.write_outputs(study, args.env_id, out):
        print(line, flush=True)
    if interrupted:
        return EXIT_INTERRUPTED
    if progress.finished and all(state == "FAIL" for state in progress.finished):
        return 1
    return 0


def _hide_password(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        base, out, url = check_args(args)
        return run(args, base, out, url)
    except UsageError as exc:
        parser.exit(EXIT_USAGE, f"snake-tune: error: {exc}\n")
    except KeyboardInterrupt:
        parser.exit(EXIT_INTERRUPTED, "snake-tune: interrupted\n")


if __name__ == "__main__":
    sys.exit(main())
