"""Turning ``snake-bench`` results into targets, a table, markdown and a plot.

Everything here reads the results dict (the JSON ``snake-bench`` writes), so
``docs/benchmarks.md`` can be regenerated from a saved JSON without rerunning
the measurements.
"""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata

from snake_env.atomic import atomic_write_bytes, atomic_write_text, save_figure
from snake_env.benchmarks.bench_sections import snake_id

# The targets (key, description, threshold, "ge" = at least, "lt" = below): the speed issue's (start in
# seconds, step faster: 4x, 120x, 1 s warm, 10 s cold), the others from the first benchmark's
TARGETS = (
    ("snake3_vs_swimmer", "Snake3 single env / Swimmer-v5 single env (steps/s)", 4.0, "ge"),
    ("snake5_1024_vs_swimmer", "Snake5 vector env, 1024 envs / Swimmer-v5 single env (env-steps/s)", 120.0, "ge"),
    ("kane_t1000_over_t100", "kane udot t(n=1000) / t(n=100)", 15.0, "lt"),
    ("kane_paper_over_kane_n200", "kane_paper udot / kane udot at n=200", 10.0, "ge"),
    ("ppo_snake5_vs_swimmer", "SB3 PPO fps, Snake5 batched / Swimmer-v5 single env", 2.0, "ge"),
    ("snake30_4096_peak_mb", "peak RSS of a 4096-env Snake30 vector env (MiB)", 500.0, "lt"),
    ("startup_s", "import + first step of a fresh process, caches warm (s)", 1.0, "lt"),
    ("cold_start_s", "import + first step + first 32-env vector step, empty numba cache (s)", 10.0, "lt"),
)


# --------------------------------------------------------------------------- machine
def _lscpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return platform.processor() or "unknown"
    for line in out.splitlines():
        if line.startswith("Model name:"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown"


def _total_ram_gb() -> float | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    return round(int(line.split()[1]) / 1024.0 / 1024.0, 1)
    except OSError:
        pass
    return None


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def machine_description() -> dict:
    """CPU model, logical cores, RAM, OS, load and the versions that matter."""
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return {
        "cpu": _lscpu_model(),
        "logical_cores": os.cpu_count(),
        "ram_gb": _total_ram_gb(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "load_average_at_start": list(load) if load else None,
        "versions": {p: _version(p) for p in ("numpy", "numba", "gymnasium", "mujoco", "stable-baselines3", "torch")},
    }


# --------------------------------------------------------------------------- ratios and targets
def _get(results, *keys):
    node = results
    for key in keys:
        if not isinstance(node, dict) or key not in node:
            return None
        node = node[key]
    return node


def _ratio(a, b):
    return a / b if a is not None and b else None


def target_values(results: dict) -> dict:
    """The number behind each target, or None when its section did not run."""
    swimmer = _get(results, "single_env", "Swimmer-v5", "steps_per_s")
    udot = _get(results, "udot", "seconds_per_call") or {}
    kane = udot.get("kane", {})
    paper = udot.get("kane_paper", {})
    return {
        "snake3_vs_swimmer": _ratio(_get(results, "single_env", snake_id(3), "steps_per_s"), swimmer),
        "snake5_1024_vs_swimmer": _ratio(_get(results, "vector_env", "1024", "env_steps_per_s"), swimmer),
        "kane_t1000_over_t100": _ratio(kane.get("1000"), kane.get("100")),
        "kane_paper_over_kane_n200": _ratio(paper.get("200"), kane.get("200")),
        "ppo_snake5_vs_swimmer": _ratio(_get(results, "ppo", "snake", "fps"), _get(results, "ppo", "swimmer", "fps")),
        "snake30_4096_peak_mb": _get(results, "memory", "peak_rss_mb")
        if _get(results, "memory", "num_envs") == 4096 else None,
        "startup_s": _get(results, "startup", "import_and_first_step_s"),
        "cold_start_s": _get(results, "startup", "cold_start_s"),
    }


def derived_ratios(results: dict) -> dict:
    """Ratios beside the targets that show where the time goes (informational)."""
    udot = _get(results, "udot", "seconds_per_call") or {}
    kernel = udot.get("kane_kernel", {})
    numpy_sweep = udot.get("kane_numpy", {})
    paper = udot.get("kane_paper", {})
    swimmer = _get(results, "single_env", "Swimmer-v5", "steps_per_s")
    out = {
        "kane_kernel t(1000)/t(100)": _ratio(kernel.get("1000"), kernel.get("100")),
        "kane_numpy t(1000)/t(100)": _ratio(numpy_sweep.get("1000"), numpy_sweep.get("100")),
        "kane_paper / kane_kernel at n=200": _ratio(paper.get("200"), kernel.get("200")),
        "kane_paper / kane_numpy at n=200": _ratio(paper.get("200"), numpy_sweep.get("200")),
    }
    for env_id in (snake_id(5), snake_id(30)):
        out[f"{env_id} single / Swimmer-v5 single"] = _ratio(
            _get(results, "single_env", env_id, "steps_per_s"), swimmer)
    for num_envs in (_get(results, "vector_env") or {}):
        out[f"Snake{_get(results, 'config', 'vector_n_links')} x{num_envs} / Swimmer-v5 single"] = _ratio(
            _get(results, "vector_env", num_envs, "env_steps_per_s"), swimmer)
    return {key: value for key, value in out.items() if value is not None}


def evaluate_targets(results: dict) -> list[dict]:
    """[{key, description, threshold, value, status}], status met / not met / not measured."""
    values = target_values(results)
    rows = []
    for key, description, threshold, sense in TARGETS:
        value = values[key]
        if value is None:
            status = "not measured"
        elif (value >= threshold) if sense == "ge" else (value < threshold):
            status = "met"
        else:
            status = "not met"
        rows.append({"key": key, "description": description, "threshold": threshold,
                     "sense": ">=" if sense == "ge" else "<", "value": value, "status": status})
    return rows


# --------------------------------------------------------------------------- table
def _fmt(value, digits=3):
    if value is None:
        return "-"
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:.{digits}g}"


def table_rows(results: dict) -> list[tuple[str, str, str]]:
    """(section, item, value) rows of the result table."""
    rows = []
    for env_id, data in (_get(results, "single_env") or {}).items():
        rows.append(("single env", env_id, f"{_fmt(data['steps_per_s'])} steps/s"))
    n_links = _get(results, "config", "vector_n_links")
    for num_envs, data in (_get(results, "vector_env") or {}).items():
        rows.append(("vector env", f"Snake{n_links}, {num_envs} envs", f"{_fmt(data['env_steps_per_s'])} env-steps/s"))
    wheels = _get(results, "wheels") or {}
    for n_links, data in (wheels.get("links") or {}).items():
        rows.append(("wheel models", f"Snake{n_links}, {wheels['num_envs']} envs",
                     f"no-slip {_fmt(data['no_slip'])}, sliding {_fmt(data['sliding'])} env-steps/s "
                     f"(a sliding step costs {_fmt(data['cost_ratio'])}x)"))
    udot = _get(results, "udot", "seconds_per_call") or {}
    for method, times in udot.items():
        cells = ", ".join(f"n={n}: {seconds * 1e6:.3g}" for n, seconds in times.items())
        rows.append(("udot (us/call)", method, cells))
    ppo = _get(results, "ppo") or {}
    for name in ("snake", "swimmer"):
        if name in ppo:
            rows.append(("SB3 PPO", f"{ppo[name]['env']} x{ppo[name]['num_envs']}", f"{_fmt(ppo[name]['fps'])} fps"))
    memory = _get(results, "memory")
    if memory:
        rows.append(("memory", f"{memory['env']}, {memory['num_envs']} envs",
                     f"peak {_fmt(memory['peak_rss_mb'])} MiB (after imports {_fmt(memory['rss_after_imports_mb'])} MiB)"))
    startup = _get(results, "startup")
    if startup:
        rows.append(("startup", f"{startup['env']}, fresh process, warm cache",
                     f"{_fmt(startup['import_and_first_step_s'])} s to first step "
                     f"(process wall {_fmt(startup['process_wall_s'])} s); cold start from an empty numba cache: "
                     + (f"{_fmt(startup['first_run']['import_and_first_step_s'])} s to the first step, "
                        f"{_fmt(startup['cold_start_s'])} s with a first 32-env vector step"
                        + (f", {_fmt(startup['first_run']['all_kernels_s'])} s until the background compile "
                           f"(the kernels few steps need) finished" if "all_kernels_s" in startup["first_run"] else "")
                        if startup.get("cold_start_s") is not None else "not measured")))
    other = _get(results, "startup_no_slip")
    if other:
        settings = ", ".join(f"{name}={value!r}" for name, value in other["env_kwargs"].items())
        rows.append(("startup", f"{other['env']}, {settings}, empty numba cache",
                     f"{_fmt(other['first_run']['import_and_first_step_s'])} s to the first step, "
                     f"{_fmt(other['cold_start_s'])} s with a first 32-env vector step"))
    return rows


def _target_line(row) -> str:
    value = "-" if row["value"] is None else _fmt(row["value"])
    return f"{row['description']}: {value} (target {row['sense']} {_fmt(row['threshold'])}) -> {row['status']}"


def format_text(results: dict) -> str:
    """Plain-text table and targets for the terminal."""
    rows = table_rows(results)
    width = [max(len(r[i]) for r in rows) if rows else 0 for i in range(2)]
    lines = [f"{s:<{width[0]}}  {i:<{width[1]}}  {v}" for s, i, v in rows]
    lines.append("")
    lines.append("targets:")
    lines.extend("  " + _target_line(row) for row in results.get("targets", evaluate_targets(results)))
    lines.append("other ratios:")
    lines.extend(f"  {key}: {_fmt(value)}" for key, value in derived_ratios(results).items())
    for note in results.get("notes", []):
        lines.append(f"note: {note}")
    return "\n".join(lines)


def format_markdown(results: dict, plot_path: str | None = None, markdown_path: str | None = None) -> str:
    """``docs/benchmarks.md``: machine, command, table, targets, closing note."""
    machine = results.get("machine", {})
    versions = machine.get("versions", {})
    targets = results.get("targets") or evaluate_targets(results)
    out = ["# Benchmarks", ""]
    json_path = results.get("json") or "bench.json"
    plot_arg = f" --plot {plot_path}" if plot_path else ""
    out.append("Generated by `snake-bench` from one run; regenerate this page from the saved JSON with")
    out.append("")
    out.append("```")
    out.append(f"snake-bench --from-json {json_path} --markdown {markdown_path or 'docs/benchmarks.md'}{plot_arg}")
    out.append("```")
    out.append("")
    out.append("and measure afresh (about 2 minutes on 2 cores; a quiet machine gives the meaningful numbers) with")
    out.append("")
    out.append("```")
    out.append("snake-bench --json docs/benchmarks.json --plot docs/images/bench_scaling.png --markdown docs/benchmarks.md")
    out.append("```")
    out.append("")
    out.append("## Machine")
    out.append("")
    out.append(f"- CPU: {machine.get('cpu')}, {machine.get('logical_cores')} logical cores, {machine.get('ram_gb')} GB RAM")
    out.append(f"- OS: {machine.get('os')}")
    load = machine.get("load_average_at_start")
    if load:
        out.append(f"- load average at start (1, 5, 15 min): {', '.join(f'{x:.2f}' for x in load)}")
    out.append(f"- Python {machine.get('python')}, " + ", ".join(f"{k} {v}" for k, v in versions.items() if v))
    out.append(f"- command: `{results.get('command', 'snake-bench')}`, run at {results.get('started_utc')} "
               f"({results.get('duration_s', 0):.0f} s)")
    out.append("")
    out.append("## Results")
    out.append("")
    out.append("| section | item | value |")
    out.append("|---|---|---|")
    for section, item, value in table_rows(results):
        out.append(f"| {section} | {item} | {value} |")
    out.append("")
    out.append("Speeds are the best of the repeats (all repeats are in the JSON). The snake and")
    out.append("MuJoCo Swimmer-v5 are measured in the same process, interleaved, both made with")
    out.append("`gym.make` (default wrappers included) and stepped with the same pre-drawn random actions.")
    out.append("PPO fps is wall-clock timesteps / `learn()` time over whole iterations (rollouts and updates),")
    ppo = results.get("ppo") or {}
    if ppo:
        out.append(f"SB3 PPO settings {ppo.get('ppo_kwargs') or 'defaults'}, torch threads {ppo.get('torch_threads')}.")
    out.append("Memory (VmHWM, the kernel's peak resident size) and start-up are measured in fresh subprocesses.")
    out.append("udot series: `kane`, `kane_paper`, `lagrange`, `newton_euler` are the public")
    out.append("`SnakeModel.udot(q, u, torques, method)` on one float64 state, input checks included;")
    out.append("`kane_kernel` is the compiled O(n) sweep alone and `kane_numpy` the vectorised numpy sweep")
    out.append("(the float32 path). A method stops growing n once one call exceeds")
    out.append(f"{_get(results, 'config', 'udot_max_call_time')} s.")
    out.append("")
    if plot_path:
        rel = os.path.relpath(plot_path, os.path.dirname(os.path.abspath(markdown_path))) if markdown_path else plot_path
        out.append(f"![udot time vs n and vector env throughput]({rel})")
        out.append("")
    out.append("## Targets (issue 6)")
    out.append("")
    out.append("| target | value | threshold | status |")
    out.append("|---|---|---|---|")
    for row in targets:
        out.append(f"| {row['description']} | {_fmt(row['value'])} | {row['sense']} {_fmt(row['threshold'])} | {row['status']} |")
    out.append("")
    out.append("Other ratios (informational):")
    out.append("")
    out.extend(f"- {key}: {_fmt(value)}" for key, value in derived_ratios(results).items())
    out.append("")
    notes = results.get("notes", [])
    if notes:
        out.append("## Notes")
        out.append("")
        out.extend(f"- {note}" for note in notes)
        out.append("")
    met = sum(row["status"] == "met" for row in targets)
    out.append("## Summary")
    out.append("")
    out.append(f"{met} of {len(targets)} targets met in this run: "
               + "; ".join(f"{row['key']} = {_fmt(row['value'])} ({row['status']})" for row in targets) + ".")
    out.append("")
    return "\n".join(out)


# The hand-written part of the page: from this heading on, the page's text is kept when snake-bench
# regenerates it (the profile is measured with other tools and dated, docs/logs/profile-*.md).
KEPT_HEADING = "## Profile"


def kept_tail(markdown_path: str) -> str:
    """The text of the existing page from :data:`KEPT_HEADING` on ("" if there is none)."""
    try:
        with open(markdown_path, encoding="utf-8") as handle:
            text = handle.read()
    except OSError:
        return ""
    at = text.find("\n" + KEPT_HEADING)
    return text[at + 1:] if at >= 0 else ""


# --------------------------------------------------------------------------- files
def write_atomic(path: str, data: str | bytes) -> None:
    """Write via a temp file in the same directory, then os.replace."""
    if isinstance(data, bytes):
        atomic_write_bytes(path, data)
    else:
        atomic_write_text(path, data)


def write_plot(results: dict, path: str) -> None:
    """Log-log udot time vs n per method, and vector env-steps/s vs number of envs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for method, times in (_get(results, "udot", "seconds_per_call") or {}).items():
        ns = [int(n) for n in times]
        ax1.loglog(ns, [times[str(n)] * 1e6 for n in ns], "o-", label=method)
    ax1.set_xlabel("number of links n")
    ax1.set_ylabel("time per udot call (us)")
    ax1.set_title("udot time vs n (one float64 state)")
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=8)
    vector = _get(results, "vector_env") or {}
    if vector:
        sizes = [int(k) for k in vector]
        ax2.loglog(sizes, [vector[str(k)]["env_steps_per_s"] for k in sizes], "o-",
                   label=f"Snake{_get(results, 'config', 'vector_n_links')} vector env")
    styles = iter([("0.35", "--"), ("0.55", "-."), ("0.7", ":")])
    for env_id, data in (_get(results, "single_env") or {}).items():
        color, style = ("k", "--") if "Swimmer" in env_id else next(styles, ("0.8", ":"))
        ax2.axhline(data["steps_per_s"], ls=style, lw=1.2, color=color, label=f"{env_id} single env")
    ax2.set_xlabel("number of envs")
    ax2.set_ylabel("env-steps/s")
    ax2.set_title("throughput")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(fontsize=7)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
