"""What ``snake-tune`` writes from a study: ``best_config.yaml`` (a
``configs/<algo>.yaml`` entry keyed by env id), ``study.csv`` (Optuna's trials
dataframe) and the optimization-history / parameter-importance PNGs (Optuna's
matplotlib visualization). Every file is written atomically."""

from __future__ import annotations

import csv
import io
import warnings
from pathlib import Path

import yaml
from optuna.trial import TrialState

from snake_env.train.atomic import atomic_path, atomic_write_text


def completed(study) -> list:
    return [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]


def state_counts(study) -> dict[str, int]:
    counts: dict[str, int] = {}
    for trial in study.get_trials(deepcopy=False):
        counts[trial.state.name] = counts.get(trial.state.name, 0) + 1
    return counts


def write_best_config(study, env_id: str, path: Path) -> bool:
    """The best completed trial's config as ``{env_id: entry}``; False when
    no trial has completed yet."""
    if not completed(study):
        return False
    best = study.best_trial
    entry = best.user_attrs["config"]
    header = (f"# snake-tune study {study.study_name!r}: best of {len(completed(study))} completed trials is "
              f"trial {best.number},\n# mean forward speed {best.value:.4f} m/s (deterministic policy, "
              f"{entry['n_eval_episodes']} episodes) after n_timesteps = {entry['n_timesteps']} steps.\n"
              f"# Format of configs/<algo>.yaml; use with snake-train --config {path.name}\n")
    body = yaml.safe_dump({env_id: entry}, sort_keys=False, default_flow_style=None)
    atomic_write_text(path, header + body)
    return True


def write_csv(study, path: Path) -> None:
    """The columns of Optuna's ``trials_dataframe()`` (number, value, times,
    ``params_<name>``, state, intermediate values), written with the csv module
    so that pandas is not needed."""
    trials = study.get_trials(deepcopy=False)
    params = sorted({name for trial in trials for name in trial.params})
    steps = sorted({step for trial in trials for step in trial.intermediate_values})
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["number", "value", "datetime_start", "datetime_complete", "duration",
                     *(f"params_{name}" for name in params), "state",
                     *(f"intermediate_{step}" for step in steps)])
    for trial in trials:
        writer.writerow([trial.number, "" if trial.value is None else trial.value,
                         trial.datetime_start or "", trial.datetime_complete or "",
                         "" if trial.duration is None else trial.duration.total_seconds(),
                         *(trial.params.get(name, "") for name in params), trial.state.name,
                         *(trial.intermediate_values.get(step, "") for step in steps)])
    atomic_write_text(path, buffer.getvalue())


def write_plots(study, history_path: Path, importance_path: Path) -> list[str]:
    """Optuna's matplotlib plots; returns one-line notes for plots that could
    not be drawn (e.g. parameter importances need two completed trials with
    varying parameters). Importances use PED-ANOVA, which needs no scikit-learn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.importance import PedAnovaImportanceEvaluator
    from optuna.visualization import matplotlib as optuna_plt

    notes = []
    jobs = ((history_path, lambda: optuna_plt.plot_optimization_history(study, target_name="mean forward speed (m/s)")),
            (importance_path, lambda: optuna_plt.plot_param_importances(
                study, evaluator=PedAnovaImportanceEvaluator(), target_name="mean forward speed")))
    for path, draw in jobs:
        if not completed(study):
            notes.append(f"{path.name} not drawn: no completed trial")
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                axes = draw()
                figure = axes.figure
                figure.set_size_inches(8, 5)
                figure.tight_layout()
                with atomic_path(path, suffix=".png") as tmp:
                    figure.savefig(tmp, dpi=100)
                plt.close(figure)
        except (ValueError, RuntimeError, ZeroDivisionError) as exc:
            plt.close("all")
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            notes.append(f"{path.name} not drawn: {first}")
    return notes


def write_outputs(study, env_id: str, out: Path) -> list[str]:
    """Write every result file into ``out``; returns lines for the summary."""
    lines = []
    write_csv(study, out / "study.csv")
    lines.append(f"trials table: {out / 'study.csv'}")
    if write_best_config(study, env_id, out / "best_config.yaml"):
        lines.append(f"best config: {out / 'best_config.yaml'}")
    notes = write_plots(study, out / "optimization_history.png", out / "param_importances.png")
    for name in ("optimization_history.png", "param_importances.png"):
        if (out / name).is_file() and not any(note.startswith(name) for note in notes):
            lines.append(f"plot: {out / name}")
    return lines + notes

