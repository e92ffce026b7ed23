"""Search of serpenoid-gait parameters per env id (CMA-ES from the ``cma`` package).

Both gait families of :mod:`snake_env.controllers.serpenoid` are searched: uniform random
samples in a box, then a few generations of CMA-ES (Hansen's ``cma``,
bounded to the box by its ``BoundTransform``) started from the best random
gait, in box-normalized coordinates. A whole population is one batched
vector env (one gait per sub-env), so a generation is one rollout.
Every gait is scored on a few random starts; the best few of each family
are re-scored on many full-length episodes and the best mean is written to ``serpenoid.yaml`` under the env id
(the file :func:`snake_env.configfiles.config_path` resolves: ``./configs/serpenoid.yaml`` when it exists).

Score: mean forward speed of the snake's centre of mass, the mean of the
env's ``info["x_velocity"]`` (m/s) over the episode, i.e. x displacement / time.
With ``max_outside_share`` (``--max-outside-share``), a gait whose wheels leave the
friction cone (``info["wheel_slip"]``) on more than that share of wheel-steps scores
below every gait within it, by how far it is over (so CMA-ES is led back inside), and
only finalists within it can win: the searched gait is one real wheels can run.

    python -m snake_env.agents.search --env snake_env/Snake5-v2
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from dataclasses import dataclass

import numpy as np
import yaml

from snake_env.atomic import atomic_write_text

from snake_env.configfiles import config_path
from snake_env.controllers.gaits import GAITS_FILE, load_gaits
from snake_env.controllers.serpenoid import FAMILIES, SerpenoidController, SerpenoidParams


# Search boxes: (name, low, high, log-scale). Frequencies up to 40 rad/s keep
# >= 4 env steps (0.04 s each, the policy's control period too) per gait
# period; "pd" amplitudes stay inside the default +-90 deg joint limit.
BOXES = {
    "torque": (("amplitude", 0.05, 1.0, False), ("frequency", 0.5, 40.0, True),
               ("phase_lag", -math.pi, math.pi, False)),
    "pd": (("amplitude", 0.05, 1.5, False), ("frequency", 0.5, 40.0, True),
           ("phase_lag", -math.pi, math.pi, False), ("kp", 0.3, 30.0, True), ("kd", 0.0, 2.0, False)),
}


@dataclass
class SearchResult:
    params: SerpenoidParams
    speed: float  # m/s, mean over the final re-scoring episodes
    speed_std: float  # m/s, over those episodes
    evaluated: int  # gaits rolled out during the search
    seconds: float
    outside_share: float = math.nan  # share of wheel-steps outside the friction cone, final re-scoring
    max_outside_share: float | None = None  # the search's limit on it (None: none)


def env_geometry(env_id: str, env_kwargs: dict) -> tuple[int, float, float, bool]:
    """(n_links, max_torque (N m), dt (s), include_position) of a registered snake id, read from its
    physics config (no env is built)."""
    from snake_env.envs.core import env_config
    from snake_env.tasks.base import controller_geometry

    g = controller_geometry(env_config(env_id, env_kwargs)[1])
    return g["n_links"], g["max_torque"], g["dt"], g["include_position"]


# Work-energy check (the paper's section VI.3): K(t) - K(0) equals the work of all loads
# (info "power" x dt) for the continuous model; the fixed-step RK4 leaves a
# residual of a few % of K over an episode (docs/results.md: -2.8 J at K ~ 80 J
# under a trained Snake5 policy). A runaway integration breaks it by orders of
# magnitude while the state can stay finite, and a search is drawn to such
# runaways (a 93 m/s "gait" on Snake30), so a rollout whose residual exceeds
# this fraction of its largest K (plus 1 J) scores as failed.
ENERGY_RESIDUAL_TOLERANCE = 0.2
FAILED_SCORE = -100.0  # m/s, search score of a failed or non-physical rollout (far below any gait)


def rollout_speeds(env_id: str, env_kwargs: dict, plist, n_steps: int, seed: int) -> np.ndarray:
    """Mean forward CM speed (m/s) of each gait in ``plist`` over ``n_steps``
    env steps, all gaits stepped together in one batched vector env.

    A gait whose rollout ended early (the env's ``sim_failure`` truncation) or
    broke the work-energy balance gets NaN: its speed is not physical."""
    return rollout_scores(env_id, env_kwargs, plist, n_steps, seed)[0]


def rollout_scores(env_id: str, env_kwargs: dict, plist, n_steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(speeds, outside shares) of :func:`rollout_speeds`: also each gait's share of wheel-steps outside
    the friction cone (``info["wheel_slip"]``; 0 with unlimited grip), NaN where the speed is."""
    import gymnasium as gym

    import snake_env  # noqa: F401

    n_links, max_torque, dt, include_position = env_geometry(env_id, env_kwargs)
    num = len(plist)
    envs = gym.make_vec(env_id, num_envs=num, vectorization_mode="vector_entry_point", **env_kwargs)
    try:
        controller = SerpenoidController(plist, n_links, max_torque, dt, num_envs=num,
                                         include_position=include_position)
        obs, info = envs.reset(seed=seed)
        kinetic0 = np.asarray(info["kinetic_energy"], dtype=np.float64)
        work = np.zeros(num)
        peak = kinetic0.copy()
        total = np.zeros(num)
        slipping = np.zeros(num)
        failed = np.zeros(num, bool)
        for step in range(n_steps):
            # a runaway state can overflow the float32 observation: such a row
            # is failed already; give it a zero action so the batch can go on
            bad_obs = ~np.isfinite(obs).all(axis=1)
            failed |= bad_obs
            action = controller.act(np.where(bad_obs[:, None], 0.0, obs))
            action[failed] = 0.0
            obs, _, terminated, truncated, info = envs.step(action)
            total += np.asarray(info["x_velocity"], dtype=np.float64)
            if "wheel_slip" in info:
                slipping += np.asarray(info["wheel_slip"]).mean(axis=1)
            kinetic = np.asarray(info["kinetic_energy"], dtype=np.float64)
            work += np.asarray(info["power"], dtype=np.float64) * dt
            peak = np.maximum(peak, kinetic)
            residual = np.abs(kinetic - kinetic0 - work)
            # n_steps never exceeds the episode length, so an earlier episode end is a failure
            ended = terminated | truncated if step < n_steps - 1 else terminated
            failed |= ended | ~np.isfinite(residual)
            failed |= residual > ENERGY_RESIDUAL_TOLERANCE * peak + 1.0
            if failed.all():
                break
        speeds = total / n_steps
        shares = slipping / n_steps
        speeds[failed] = np.nan
        shares[failed] = np.nan
        return speeds, shares
    finally:
        envs.close()


def _decode(family: str, unit: np.ndarray) -> list[SerpenoidParams]:
    """Box-normalized points in [0, 1]^d -> gaits."""
    box = BOXES[family]
    out = []
    for row in np.clip(unit, 0.0, 1.0):
        values = {}
        for x, (name, low, high, log) in zip(row, box):
            values[name] = float(math.exp(math.log(low) + x * (math.log(high) - math.log(low)))) if log \
                else float(low + x * (high - low))
        out.append(SerpenoidParams(family=family, **values))
    return out


def search_family(family: str, score, rng: np.random.Generator, population: int, generations: int,
                  elite: int) -> tuple[np.ndarray, np.ndarray]:
    """Random search, then ``generations`` CMA-ES generations of ``population``
    gaits from the best random one; return (unit points, scores) of every gait tried.

    ``elite`` is CMA-ES's parent number mu (its recombination weights are the
    package's defaults). The phase lag is periodic, so its coordinate is left
    unbounded and wrapped into the box when decoded.
    """
    import cma

    dim = len(BOXES[family])
    points = rng.uniform(size=(population, dim))
    scores = score(_decode(family, points))
    tried_points, tried_scores = [points], [scores]
    if generations == 0:
        return points, scores
    lag = [name for name, *_ in BOXES[family]].index("phase_lag")
    lower, upper = [0.0] * dim, [1.0] * dim
    lower[lag] = upper[lag] = None
    es = cma.CMAEvolutionStrategy(points[int(np.argmax(scores))], 0.2, {
        "bounds": [lower, upper], "popsize": population, "CMA_mu": min(elite, population // 2 or 1),
        "seed": int(rng.integers(1, 2**31)), "verbose": -9, "verb_log": 0, "verb_disp": 0,
        "maxiter": generations, "tolfun": 0, "tolx": 0, "tolfunhist": 0, "tolstagnation": 10**6,
    })
    for _ in range(generations):
        asked = es.ask()
        children = np.array(asked)
        children[:, lag] %= 1.0
        children = np.clip(children, 0.0, 1.0)  # the bound transform keeps the rest inside already
        child_scores = score(_decode(family, children))
        es.tell(asked, list(-child_scores))  # cma minimizes
        tried_points.append(children)
        tried_scores.append(child_scores)
    return np.concatenate(tried_points), np.concatenate(tried_scores)


def search(env_id: str, env_kwargs: dict | None = None, families=FAMILIES, population: int = 192,
           generations: int = 10, elite: int = 8, search_steps: int = 400, repeats: int = 3,
           final_steps: int = 1000, final_episodes: int = 16, finalists: int = 6, seed: int = 0,
           max_outside_share: float | None = None) -> SearchResult:
    """Best serpenoid gait for ``env_id`` over both families (see module doc).
    ``max_outside_share``: the largest share of wheel-steps outside the friction cone a gait may have
    (None: no limit).

    Every gait is scored on ``repeats`` random starts during the search and the
    ``finalists`` best of each family on ``final_episodes`` full-length
    episodes: fast gaits can be fragile (another start falls into a slow
    cycle), and the mean over many starts is what an evaluation measures.
    """
    env_kwargs = dict(env_kwargs or {})
    for name, value in (("population", population), ("elite", elite), ("search_steps", search_steps),
                        ("repeats", repeats), ("final_steps", final_steps), ("final_episodes", final_episodes),
                        ("finalists", finalists)):
        if not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if max_outside_share is not None and not 0.0 <= max_outside_share < 1.0:
        raise ValueError(f"max_outside_share must be in [0, 1) or None, got {max_outside_share!r}")
    if not isinstance(generations, int) or generations < 0:
        raise ValueError(f"generations must be an integer >= 0, got {generations!r}")
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise ValueError(f"families must be a non-empty subset of {list(FAMILIES)}, got {list(families)}")
    rng = np.random.default_rng(seed)
    started = time.perf_counter()
    evaluated = 0
    candidates = []
    for family in families:
        def score(plist):
            nonlocal evaluated
            evaluated += len(plist) * repeats
            speeds, shares = rollout_scores(env_id, env_kwargs, list(plist) * repeats, search_steps,
                                            int(rng.integers(2**31)))
            scores = speeds.reshape(repeats, len(plist)).mean(axis=0)
            if max_outside_share is not None:
                scores = limit_slip(scores, shares.reshape(repeats, len(plist)).mean(axis=0), max_outside_share)
            return np.where(np.isnan(scores), FAILED_SCORE, scores)

        points, scores = search_family(family, score, rng, population, generations, min(elite, population))
        order = np.argsort(-scores)[:finalists]
        candidates += _decode(family, points[order])
    # re-score the finalists of both families on full episodes from fresh starts
    per_episode, shares = final_scores(env_id, env_kwargs, candidates, final_steps, final_episodes, seed + 1000,
                                       with_shares=True)
    mean = per_episode.mean(axis=0)  # NaN if any episode failed or was not physical
    if max_outside_share is not None:
        mean = np.where(shares.mean(axis=0) <= max_outside_share, mean, np.nan)
    if np.isnan(mean).all():
        within = "" if max_outside_share is None else f" or left the friction cone on more than {max_outside_share}"
        raise ValueError(f"every finalist gait of {env_id} failed or broke the work-energy balance{within}; "
                         f"widen the search")
    best = int(np.nanargmax(mean))
    return SearchResult(params=candidates[best], speed=float(mean[best]), speed_std=float(per_episode[:, best].std()),
                        evaluated=evaluated + len(candidates) * final_episodes,
                        seconds=time.perf_counter() - started, outside_share=float(shares[:, best].mean()),
                        max_outside_share=max_outside_share)


def limit_slip(scores: np.ndarray, shares: np.ndarray, max_share: float) -> np.ndarray:
    """Scores of gaits with these outside-cone shares: unchanged within ``max_share``; above it, minus
    the share over it below zero, so that every gait over the limit ranks below every gait within it
    that moves forward, and a gait nearer the limit above one farther out."""
    over = shares - max_share
    return np.where(over <= 0.0, scores, np.minimum(scores, 0.0) - over)


def final_scores(env_id: str, env_kwargs: dict, candidates, steps: int, episodes: int, seed: int,
                 with_shares: bool = False):
    """Speeds (episodes, len(candidates)) (m/s), all in one batched rollout; with ``with_shares``
    also the outside-cone shares of the same shape."""
    speeds, shares = rollout_scores(env_id, env_kwargs, list(candidates) * episodes, steps, seed)
    shape = (episodes, len(candidates))
    return (speeds.reshape(shape), shares.reshape(shape)) if with_shares else speeds.reshape(shape)


def save_result(env_id: str, env_kwargs: dict, result: SearchResult, path=None, note: str = "") -> None:
    """Merge the result into the gait file (``path``, else the one :func:`config_path` resolves) under
    ``env_id`` (atomic write)."""
    path = config_path(GAITS_FILE, path)
    data = load_gaits(path)
    data[env_id] = {
        "params": result.params.to_dict(),
        "env_kwargs": dict(env_kwargs),
        "search": {"mean_forward_velocity": round(result.speed, 5), "std_forward_velocity": round(result.speed_std, 5),
                   "outside_friction_cone_share": round(result.outside_share, 5),
                   **({"max_outside_friction_cone_share": result.max_outside_share}
                      if result.max_outside_share is not None else {}),
                   "gaits_evaluated": result.evaluated, "seconds": round(result.seconds, 1),
                   **({"note": note} if note else {})},
    }
    header = ("# Serpenoid gaits found by `python -m snake_env.agents.search --env ID` (see snake_env/agents/search.py).\n"
              "# params: snake_env.controllers.serpenoid.SerpenoidParams; velocities in m/s (CM, along x).\n")
    text = header + yaml.safe_dump(dict(sorted(data.items())), sort_keys=False)
    atomic_write_text(path, text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.agents.search", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", dest="env_id", required=True, help="gymnasium env id, e.g. snake_env/Snake5-v2")
    parser.add_argument("--families", nargs="+", default=list(FAMILIES), help=f"subset of {list(FAMILIES)}")
    parser.add_argument("--population", type=int, default=192)
    parser.add_argument("--generations", type=int, default=10)
    parser.add_argument("--search-steps", type=int, default=400, help="env steps per search rollout")
    parser.add_argument("--repeats", type=int, default=3, help="random starts per gait during the search")
    parser.add_argument("--final-episodes", type=int, default=16, help="episodes of the finalists' re-scoring")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", default=None, help="YAML to merge the result into (default: ./configs/"
                        "serpenoid.yaml when it exists, else the shipped file)")
    parser.add_argument("--n-links", type=int, default=None,
                        help="a length with no id of its own, on the generic id (--env snake_env/Snake-vN): the "
                             "gait is saved as snake_env/Snake{n}-vN, where the baselines of n_links=n look")
    parser.add_argument("--max-outside-share", type=float, default=None,
                        help="largest share of wheel-steps outside the friction cone a gait may have, in [0, 1) "
                             "(default: no limit)")
    parser.add_argument("--dry-run", action="store_true", help="print the result, do not write it")
    args = parser.parse_args(argv)
    env_kwargs, key = {}, args.env_id
    if args.n_links is not None:
        generic = re.fullmatch(r"(snake_env/Snake)-(v\d+)", args.env_id)
        if generic is None or args.n_links < 2:
            parser.exit(2, f"{parser.prog}: error: --n-links needs the generic id snake_env/Snake-vN and an "
                           f"integer >= 2, got --env {args.env_id} --n-links {args.n_links}\n")
        env_kwargs, key = {"n_links": args.n_links}, f"{generic[1]}{args.n_links}-{generic[2]}"
    try:
        result = search(args.env_id, env_kwargs, families=args.families, population=args.population,
                        generations=args.generations, search_steps=args.search_steps, repeats=args.repeats,
                        final_episodes=args.final_episodes, seed=args.seed,
                        max_outside_share=args.max_outside_share)
    except ValueError as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    print(f"{key}: {result.params} -> {result.speed:.4f} +- {result.speed_std:.4f} m/s, "
          f"{100 * result.outside_share:.2f} % of wheel-steps outside the friction cone "
          f"({result.evaluated} gaits, {result.seconds:.0f} s)")
    if not args.dry_run:
        import cma

        note = (f"cma {cma.__version__} CMA-ES after random search: `python -m snake_env.agents.search --env {args.env_id} "
                f"--families {' '.join(args.families)} --population {args.population} --generations {args.generations} "
                f"--search-steps {args.search_steps} --repeats {args.repeats} --final-episodes {args.final_episodes} "
                f"--seed {args.seed}{f' --n-links {args.n_links}' if args.n_links is not None else ''}"
                f"{f' --max-outside-share {args.max_outside_share}' if args.max_outside_share is not None else ''}`")
        save_result(key, env_kwargs, result, args.output, note=note)
        print(f"saved to {config_path(GAITS_FILE, args.output)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
