"""Training configuration as data, RL Baselines3 Zoo style.

A hyperparameter YAML (``configs/ppo.yaml``, ``configs/sac.yaml``) is keyed by
env id; each entry mixes the zoo's meta keys (``policy``, ``n_timesteps``,
``n_envs``, ``normalize``, ``policy_kwargs``, ``env_kwargs``) with the
algorithm's constructor arguments (``gamma``, ``n_steps``, ...). The config
flows once: YAML entry -> ``--set key=value`` overrides -> explicit CLI flags
(``--total-timesteps``, ``--n-envs``, ``--seed``), merged into one flat dict
that is validated here and saved as ``config.yaml`` beside the model.

Unknown keys and unknown algorithms are errors that list the valid ones.
"""

from __future__ import annotations

import ast
import copy
import inspect
import numbers
from pathlib import Path

import yaml

from snake_env.configfiles import config_path, shipped_config_path  # noqa: F401  (re-exported)
from snake_env.train.atomic import atomic_write_text

ALGOS = ("ppo", "sac")

# Keys that are not algorithm constructor arguments (the zoo's meta keys plus
# the run-control keys of this project).
META_DEFAULTS = {
    "policy": "MlpPolicy",
    "n_timesteps": 100_000,
    "n_envs": 1,
    # zoo convention: true -> VecNormalize(norm_obs=True, norm_reward=True);
    # a dict (or its string form) -> VecNormalize(**dict)
    "normalize": False,
    "policy_kwargs": {},
    "env_kwargs": {},
    # "batched": one SnakeSB3VecEnv over the batched vector env; "dummy": SB3 DummyVecEnv
    "vec_env": "batched",
    "eval_freq": 20_000,  # env steps (summed over envs) between evaluations
    "n_eval_episodes": 4,
    "checkpoint_freq": 50_000,  # env steps (summed over envs) between checkpoints
    "torch_threads": 1,  # the training machine is shared; 1 thread avoids oversubscription
    # opt-in observation/action modes (snake_env.wrappers), RL Zoo's key name:
    # a mapping {name: kwargs} applied in order, e.g. {joint_target: {kp: 1.0}}
    "env_wrapper": None,
    # extra SB3 callbacks, RL Zoo's key and form: a dotted class name, or a list of names and
    # one-key mappings {dotted name: kwargs}, e.g. [{snake_env.train.callbacks.ResidualBurnIn: {burn_in_steps: 40000}}]
    "callback": None,
    # several snake sizes in one run (policy JointPolicy only): a list of link counts, e.g. [5, 8, 12];
    # snake_env.train.multi_n_env pads them to the longest
    "n_links_set": None,
    # exploration noise, RL Zoo's key: "pink" (SAC, PPO) samples rollout actions with pink noise
    # (snake_env.train.exploration)
    "noise_type": None,
    # fine-tuning: a run directory (its model.zip) or a model .zip whose policy weights start this run,
    # e.g. a JointPolicy trained on other sizes (snake-train --init-from); RL Zoo's --trained-agent
    # continues a whole model instead
    "init_from": None,
}
# the shared per-joint policy (snake_env.train.joint_policy), for PPO and SAC
JOINT_POLICY = "JointPolicy"
RUN_KEYS = ("algo", "env_id", "seed")
VEC_ENV_KINDS = ("batched", "dummy")
NORMALIZE_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon")
# filled by the algorithm, never by the user
_RESERVED_ALGO_ARGS = {"self", "policy", "env", "verbose", "tensorboard_log", "seed", "device",
                       "_init_setup_model", "policy_kwargs", "stats_window_size"}
# string values of these keys may be zoo-style schedules "lin_<float>"
SCHEDULE_KEYS = ("learning_rate", "clip_range")
# zoo-style names of SB3 replay buffers accepted for ``replay_buffer_class`` (off-policy algorithms)
REPLAY_BUFFERS = ("ReplayBuffer", "DictReplayBuffer", "HerReplayBuffer")
ACTIVATIONS = {"nn.ReLU": "ReLU", "nn.Tanh": "Tanh", "nn.ELU": "ELU", "nn.LeakyReLU": "LeakyReLU",
               "nn.SiLU": "SiLU", "nn.GELU": "GELU"}


class ConfigError(ValueError):
    """A configuration problem; the message is one line fit for a CLI error."""


def first_line(exc: BaseException) -> str:
    """An exception's first message line (its type's name when it has no message), for a one-line error."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def algo_class(algo: str):
    from stable_baselines3 import PPO, SAC

    check_algo(algo)
    return {"ppo": PPO, "sac": SAC}[algo]


def check_algo(algo) -> str:
    if algo not in ALGOS:
        raise ConfigError(f"algo must be one of {list(ALGOS)}, got {algo!r}")
    return algo


def algo_arguments(algo: str) -> list[str]:
    """Constructor arguments of the SB3 algorithm that a config may set."""
    params = inspect.signature(algo_class(algo).__init__).parameters
    return sorted(p for p in params if p not in _RESERVED_ALGO_ARGS)


def valid_keys(algo: str) -> list[str]:
    return sorted(set(META_DEFAULTS) | set(RUN_KEYS) | set(algo_arguments(algo)))


def default_config_path(algo: str) -> Path:
    return config_path(f"{check_algo(algo)}.yaml")


def coerce_scalar(value):
    """YAML 1.1 reads ``3e-4`` as a string; numbers written that way become floats."""
    if isinstance(value, str):
        try:
            as_float = float(value)
        except ValueError:
            return value
        if value.strip().lower() in ("nan", "inf", "-inf", "+inf", "infinity", "-infinity"):
            return value
        return int(as_float) if as_float.is_integer() and "." not in value and "e" not in value.lower() else as_float
    if isinstance(value, dict):
        return {k: coerce_scalar(v) for k, v in value.items()}
    if isinstance(value, list):
        return [coerce_scalar(v) for v in value]
    return value


def parse_python_dict(text: str, name: str) -> dict:
    """Parse a zoo-style ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"`` or
    ``"{'norm_obs': True}"`` string without ``eval``: only literals, ``dict(...)``
    calls and the activation names of :data:`ACTIVATIONS` are accepted."""
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError:
        raise ConfigError(f"{name} must be a mapping or a string like \"dict(net_arch=[64, 64])\", got {text!r}") from None

    def convert(node):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
            return {kw.arg: convert(kw.value) for kw in node.keywords}
        if isinstance(node, ast.Dict):
            return {convert(k): convert(v) for k, v in zip(node.keys, node.values)}
        if isinstance(node, (ast.List, ast.Tuple)):
            return [convert(e) for e in node.elts]
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            dotted = f"{node.value.id}.{node.attr}"
            if dotted in ACTIVATIONS:
                return dotted
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant):
            return -node.operand.value
        raise ConfigError(f"{name}: unsupported expression {ast.unparse(node)!r} (use literals, dict(...), "
                          f"or one of {sorted(ACTIVATIONS)})")

    value = convert(tree.body)
    if not isinstance(value, dict):
        raise ConfigError(f"{name} must describe a mapping, got {text!r}")
    return value


def python_text(value) -> str:
    """``{"net_arch": [64], "activation_fn": "nn.Tanh"}`` -> ``"dict(net_arch=[64], activation_fn=nn.Tanh)"``,
    the form ``configs/*.yaml`` use, :func:`parse_python_dict` reads and RL Zoo ``eval``s."""
    if isinstance(value, dict):
        if all(isinstance(k, str) and k.isidentifier() for k in value):
            return "dict(" + ", ".join(f"{k}={python_text(v)}" for k, v in value.items()) + ")"
        return "{" + ", ".join(f"{k!r}: {python_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(python_text(v) for v in value) + "]"
    if isinstance(value, str) and value in ACTIVATIONS:
        return value
    return repr(value)


def read_yaml(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file {path} is not valid YAML: {first_line(exc)}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {path} must hold a mapping, got {type(data).__name__}")
    return data


def hyperparams_for(env_id: str, algo: str, path=None) -> dict:
    """The YAML entry for ``env_id`` (zoo style: top-level keys are env ids)."""
    path = default_config_path(algo) if path is None else Path(path)
    data = read_yaml(path)
    if env_id not in data:
        known = sorted(k for k in data if not str(k).startswith("."))
        raise ConfigError(f"no {algo} hyperparameters for env {env_id!r} in {path}; available env ids: {known}")
    entry = data[env_id]
    if not isinstance(entry, dict):
        raise ConfigError(f"entry {env_id!r} of {path} must be a mapping")
    return coerce_scalar(copy.deepcopy(entry))


def parse_override(text: str) -> tuple[list[str], object]:
    """``key=value`` or ``env_kwargs.max_torque=2.0``; the value is read as YAML."""
    if "=" not in text:
        raise ConfigError(f"--set expects key=value, got {text!r}")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--set expects key=value with a non-empty key, got {text!r}")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    return key.split("."), coerce_scalar(value)


def apply_overrides(config: dict, overrides) -> dict:
    """Apply ``--set`` overrides in order; dotted keys reach into mapping values
    (``policy_kwargs`` given as a zoo string is parsed into a mapping first)."""
    config = copy.deepcopy(config)
    for text in overrides or ():
        path, value = parse_override(text)
        target = config
        for depth, part in enumerate(path[:-1]):
            child = target.get(part, {})
            if isinstance(child, str):
                child = parse_python_dict(child, ".".join(path[: depth + 1]))
            if not isinstance(child, dict):
                raise ConfigError(f"--set {text!r}: {'.'.join(path[: depth + 1])} is not a mapping")
            target[part] = child
            target = child
        target[path[-1]] = value
    return config


def normalize_options(value, gamma) -> dict | None:
    """VecNormalize kwargs for the zoo's ``normalize`` key (None: no normalization)."""
    if isinstance(value, str):
        value = parse_python_dict(value, "normalize")
    if value is False or value is None:
        return None
    if value is True:
        options = {"norm_obs": True, "norm_reward": True}
    elif isinstance(value, dict):
        unknown = sorted(set(value) - set(NORMALIZE_KEYS))
        if unknown:
            raise ConfigError(f"unknown normalize key(s) {unknown}; valid: {list(NORMALIZE_KEYS)}")
        options = dict(value)
    else:
        raise ConfigError(f"normalize must be true, false or a mapping of {list(NORMALIZE_KEYS)}, got {value!r}")
    if gamma is not None:
        options.setdefault("gamma", gamma)
    return options


def policy_kwargs_dict(value) -> dict:
    if value is None:
        return {}
    if isinstance(value, str):
        return parse_python_dict(value, "policy_kwargs")
    if not isinstance(value, dict):
        raise ConfigError(f"policy_kwargs must be a mapping or a zoo-style string, got {value!r}")
    return dict(value)


def _check_positive_int(config, key):
    value = config[key]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ConfigError(f"{key} must be a positive integer, got {config[key]!r}")
    config[key] = int(value)


def init_weights_path(value) -> Path:
    """The model .zip of ``init_from``: a run directory's model.zip, or a .zip itself; else a one-line error."""
    path = Path(value) if isinstance(value, (str, Path)) and str(value) else None
    if path is not None and path.is_dir():
        path = path / "model.zip"
    if path is None or path.suffix != ".zip" or not path.is_file():
        raise ConfigError(f"init_from must be a run directory with a model.zip or a model .zip file, got {value!r}")
    return path


def validate(config: dict) -> dict:
    """Check keys and the meta values; return a normalized copy."""
    config = copy.deepcopy(config)
    algo = check_algo(config.get("algo"))
    if not isinstance(config.get("env_id"), str) or not config["env_id"]:
        raise ConfigError(f"env_id must be a gymnasium env id string, got {config.get('env_id')!r}")
    unknown = sorted(set(config) - set(valid_keys(algo)))
    if unknown:
        raise ConfigError(f"unknown config key(s) {unknown} for {algo}; valid keys: {valid_keys(algo)}")
    for key, default in META_DEFAULTS.items():
        config.setdefault(key, copy.deepcopy(default))
    seed = config.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    config["seed"] = int(seed)
    for key in ("n_timesteps", "n_envs", "eval_freq", "n_eval_episodes", "checkpoint_freq", "torch_threads"):
        _check_positive_int(config, key)
    if config["vec_env"] not in VEC_ENV_KINDS:
        raise ConfigError(f"vec_env must be one of {list(VEC_ENV_KINDS)}, got {config['vec_env']!r}")
    if not isinstance(config["env_kwargs"], dict):
        raise ConfigError(f"env_kwargs must be a mapping, got {config['env_kwargs']!r}")
    if config["init_from"] is not None:
        init_weights_path(config["init_from"])
    policy_kwargs_dict(config["policy_kwargs"])  # parse once to report errors early
    from snake_env.wrappers import parse_env_wrapper

    try:
        wrappers = parse_env_wrapper(config["env_wrapper"])
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    goal_derived = sorted({name for name, kwargs in wrappers if name in ("goal_frame", "serpenoid_residual")
                           or (name == "steering_residual" and kwargs.get("baseline", "task") == "task")})
    if goal_derived and config.get("replay_buffer_class") == "HerReplayBuffer":
        # HER relabels desired_goal in stored transitions; these wrappers computed from the original goal
        raise ConfigError(f"env_wrapper {goal_derived} does not combine with replay_buffer_class HerReplayBuffer "
                          f"(it reads the goal that HER relabels)")
    normalize_options(config["normalize"], None)
    check_joint_policy(config)
    from snake_env.train.exploration import check_noise_type

    try:
        check_noise_type(config)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    for key in SCHEDULE_KEYS:
        value = config.get(key)
        if isinstance(value, str):
            parse_schedule(key, value)
    if "replay_buffer_class" in config and config["replay_buffer_class"] not in (None, *REPLAY_BUFFERS):
        raise ConfigError(f"replay_buffer_class must be one of {list(REPLAY_BUFFERS)}, got {config['replay_buffer_class']!r}")
    if isinstance(config.get("replay_buffer_kwargs"), str):
        parse_python_dict(config["replay_buffer_kwargs"], "replay_buffer_kwargs")
    if config["callback"] is not None:
        from snake_env.train.callbacks import ResidualBurnIn, SlipCostLagrangian, SlipCostSchedule

        callbacks = make_callbacks(config)
        for kind in (SlipCostSchedule, SlipCostLagrangian):
            if any(isinstance(c, kind) for c in callbacks):
                weight = config["env_kwargs"].get("slip_cost_weight", 0.0)
                if isinstance(weight, bool) or not isinstance(weight, numbers.Real) or not weight > 0:
                    raise ConfigError(f"callback {kind.__name__} needs env_kwargs slip_cost_weight > 0 "
                                      f"({kind.WEIGHT_ROLE}), got {weight!r}")
        if sum(isinstance(c, (SlipCostSchedule, SlipCostLagrangian)) for c in callbacks) > 1:
            raise ConfigError("callback: SlipCostSchedule and SlipCostLagrangian both set the slip cost's weight; "
                              "give one of them")

        # SAC's default learning_starts is 100
        burn_ins = [c for c in callbacks if isinstance(c, ResidualBurnIn)]
        if burn_ins and algo == "sac" and config.get("learning_starts", 100) != 0:
            raise ConfigError(f"callback ResidualBurnIn needs learning_starts: 0 (SB3 acts at random before "
                              f"learning_starts), got {config.get('learning_starts', 100)!r}")
        if algo != "sac" and any(c.residual_penalty > 0.0 or not c.learn_log_std or c.actor_lr_scale != 1.0
                                 for c in burn_ins):
            raise ConfigError(f"callback ResidualBurnIn residual_penalty, learn_log_std and actor_lr_scale are SAC "
                              f"options, not {algo}")
    return config


def check_joint_policy(config: dict) -> None:
    """One-line ConfigErrors for ``policy: JointPolicy`` options and ``n_links_set`` (see
    :mod:`snake_env.train.joint_policy` and :mod:`snake_env.train.multi_n_env`)."""
    sizes = config.get("n_links_set")
    if config["policy"] != JOINT_POLICY:
        if sizes is not None:
            raise ConfigError(f"n_links_set needs policy {JOINT_POLICY} (it masks the padded joints), "
                              f"got policy {config['policy']!r}")
        return
    from snake_env.train.joint_policy import check_options

    options = policy_kwargs_dict(config["policy_kwargs"])
    act = options.get("activation_fn")
    if act is not None:
        if act not in ACTIVATIONS:
            raise ConfigError(f"policy_kwargs.activation_fn must be one of {sorted(ACTIVATIONS)}, got {act!r}")
        options["activation_fn"] = None  # a valid name; the class is filled in by torch_policy_kwargs
    try:
        check_options(config["algo"], options)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    normalize = normalize_options(config["normalize"], None)
    if normalize is not None and normalize.get("norm_obs", True):
        raise ConfigError(f"policy {JOINT_POLICY} reads raw observations (fixed scales shared by every joint, so "
                          f"one network runs on any n); set normalize norm_obs false, e.g. "
                          f"--set normalize.norm_obs=false")
    if config.get("use_sde"):
        raise ConfigError(f"policy {JOINT_POLICY} has no gSDE; set use_sde: false")
    if sizes is not None:
        from snake_env.train.multi_n_env import check_n_links_set

        try:
            config["n_links_set"] = check_n_links_set(sizes)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if config["vec_env"] != "batched" or config["env_wrapper"]:
            raise ConfigError("n_links_set needs vec_env batched and no env_wrapper (the padding reads the "
                              "forward task's own observation)")
        if "n_links" in config["env_kwargs"]:
            raise ConfigError(f"env_kwargs n_links conflicts with n_links_set {config['n_links_set']}; remove one")
        if config["n_envs"] < len(config["n_links_set"]):
            raise ConfigError(f"n_envs must be at least the number of sizes in n_links_set "
                              f"({len(config['n_links_set'])}), got {config['n_envs']}")


def callback_specs(value) -> list[tuple[str, dict]]:
    """The zoo's ``callback`` value as [(dotted class name, kwargs)]."""
    if value is None:
        return []
    out = []
    for item in value if isinstance(value, list) else [value]:
        if isinstance(item, str):
            out.append((item, {}))
        elif isinstance(item, dict) and len(item) == 1 and isinstance(next(iter(item.values())), (dict, type(None))):
            name, kwargs = next(iter(item.items()))
            out.append((name, dict(kwargs or {})))
        else:
            raise ConfigError(f"callback entries must be dotted class names or one-key mappings "
                              f"{{name: kwargs}}, got {item!r}")
    return out


def make_callbacks(config: dict) -> list:
    """Instantiate the ``callback`` entries (SB3 BaseCallback subclasses, RL Zoo style)."""
    import importlib

    from stable_baselines3.common.callbacks import BaseCallback

    callbacks = []
    for name, kwargs in callback_specs(config.get("callback")):
        module_name, _, class_name = str(name).rpartition(".")
        try:
            cls = getattr(importlib.import_module(module_name), class_name) if module_name else None
        except (ImportError, AttributeError):
            cls = None
        if not (isinstance(cls, type) and issubclass(cls, BaseCallback)):
            raise ConfigError(f"callback {name!r} is not an importable SB3 callback class "
                              f"(a dotted name such as snake_env.train.callbacks.ResidualBurnIn)")
        try:
            callbacks.append(cls(**kwargs))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"callback {name}: {first_line(exc)}") from None
    return callbacks


def replay_buffer_class(name):
    """The SB3 class of a zoo-style replay buffer name (RL Zoo: ``replay_buffer_class: HerReplayBuffer``)."""
    import stable_baselines3
    from stable_baselines3.common import buffers

    if name is None or not isinstance(name, str):
        return name
    if name not in REPLAY_BUFFERS:
        raise ConfigError(f"replay_buffer_class must be one of {list(REPLAY_BUFFERS)}, got {name!r}")
    return getattr(stable_baselines3, name, None) or getattr(buffers, name)


def parse_schedule(key: str, value):
    """Zoo schedules: ``lin_3e-4`` is a linear decay from 3e-4 to 0."""
    if isinstance(value, str):
        if not value.startswith("lin_"):
            raise ConfigError(f"{key} must be a number or 'lin_<number>', got {value!r}")
        try:
            start = float(value[4:])
        except ValueError:
            raise ConfigError(f"{key} must be a number or 'lin_<number>', got {value!r}") from None
        return lambda progress_remaining: progress_remaining * start
    return value


def build_config(algo: str, env_id: str, config_path=None, overrides=(), seed=None,
                 n_timesteps=None, n_envs=None) -> dict:
    """Merge once: YAML entry -> ``--set`` overrides -> explicit flags; validate."""
    check_algo(algo)
    config = hyperparams_for(env_id, algo, config_path)
    config = apply_overrides(config, overrides)
    for key in RUN_KEYS:
        if key in config and key != "seed":
            raise ConfigError(f"{key} cannot be set in a config entry; use --{key.replace('_', '-')}")
    config["algo"] = algo
    config["env_id"] = env_id
    if seed is not None:
        config["seed"] = seed
    if n_timesteps is not None:
        config["n_timesteps"] = n_timesteps
    if n_envs is not None:
        config["n_envs"] = n_envs
    return validate(config)


def algo_kwargs(config: dict) -> dict:
    """The algorithm constructor arguments of a validated config."""
    allowed = set(algo_arguments(config["algo"]))
    kwargs = {k: v for k, v in config.items() if k in allowed}
    for key in SCHEDULE_KEYS:
        if key in kwargs:
            kwargs[key] = parse_schedule(key, kwargs[key])
    if "replay_buffer_class" in kwargs:
        kwargs["replay_buffer_class"] = replay_buffer_class(kwargs["replay_buffer_class"])
    if isinstance(kwargs.get("replay_buffer_kwargs"), str):
        kwargs["replay_buffer_kwargs"] = parse_python_dict(kwargs["replay_buffer_kwargs"], "replay_buffer_kwargs")
    return kwargs


def policy_for(config: dict, observation_space) -> str:
    """The configured policy, with SB3's ``MultiInputPolicy`` in place of ``MlpPolicy`` for a Dict
    observation space (goal tasks), as SB3 requires."""
    from gymnasium import spaces

    policy = config["policy"]
    if isinstance(observation_space, spaces.Dict) and policy == "MlpPolicy":
        return "MultiInputPolicy"
    if policy == JOINT_POLICY:
        from snake_env.train.joint_policy import policy_class

        return policy_class(config["algo"])
    return policy


def torch_policy_kwargs(config: dict) -> dict:
    """``policy_kwargs`` with activation names turned into torch classes, and a features extractor
    named by ``features_extractor_class`` (:data:`snake_env.train.extractors.EXTRACTORS`) turned
    into its class with the env's observation layout as its kwargs."""
    import torch.nn as nn

    kwargs = policy_kwargs_dict(config["policy_kwargs"])
    act = kwargs.get("activation_fn")
    if isinstance(act, str):
        name = ACTIVATIONS.get(act, act)
        if not hasattr(nn, name) or name not in ACTIVATIONS.values():
            raise ConfigError(f"policy_kwargs.activation_fn must be one of {sorted(ACTIVATIONS)}, got {act!r}")
        kwargs["activation_fn"] = getattr(nn, name)
    if config.get("policy") == JOINT_POLICY and kwargs.get("layout") is None:
        from snake_env.train.joint_features import layout_for_id

        try:
            kwargs["layout"] = layout_for_id(config["env_id"], dict(config.get("env_kwargs") or {}))
        except ValueError as exc:
            raise ConfigError(f"policy {JOINT_POLICY} on {config['env_id']}: {first_line(exc)}") from None
    extractor = kwargs.get("features_extractor_class")
    if isinstance(extractor, str):
        from snake_env.train.extractors import EXTRACTORS

        if extractor not in EXTRACTORS:
            raise ConfigError(f"policy_kwargs.features_extractor_class must be one of {sorted(EXTRACTORS)}, "
                              f"got {extractor!r}")
        extractor_class, layout = EXTRACTORS[extractor]
        kwargs["features_extractor_class"] = extractor_class
        kwargs["features_extractor_kwargs"] = {**layout(config["env_id"], dict(config.get("env_kwargs") or {})),
                                               **dict(kwargs.get("features_extractor_kwargs") or {})}
    return kwargs


def save_config(config: dict, path) -> None:
    """Write ``config`` as YAML atomically (temp file in the same dir, then rename)."""
    text = yaml.safe_dump(config, sort_keys=False, default_flow_style=None)
    atomic_write_text(Path(path), text)


def load_run_config(path) -> dict:
    """Read and validate a run's saved ``config.yaml``."""
    data = coerce_scalar(read_yaml(path))
    return validate(data)
