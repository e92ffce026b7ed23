"""Smoke test of ``snake-bench --quick``: every section runs and its outputs are
consistent. Correctness only: speed is judged by the benchmark, never here."""

import json

import pytest

from snake_env.benchmarks import bench, bench_report
from snake_env.benchmarks.bench_sections import snake_id

SNAKE_IDS = [snake_id(3), snake_id(5), snake_id(30)]


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    paths = {"json": out / "bench.json", "plot": out / "images" / "bench_scaling.png", "markdown": out / "benchmarks.md"}
    code = bench.main(["--quick", "--json", str(paths["json"]), "--plot", str(paths["plot"]),
                       "--markdown", str(paths["markdown"])])
    assert code == 0
    return paths, json.loads(paths["json"].read_text())


def test_every_section_ran_without_error(quick_run):
    _, results = quick_run
    assert results["errors"] == {}
    for key in ("single_env", "vector_env", "udot", "ppo", "memory", "startup"):
        assert key in results, key
    assert results["quick"] is True
    assert results["machine"]["logical_cores"] >= 1


def test_speeds_are_positive_and_complete(quick_run):
    _, results = quick_run
    for env_id in SNAKE_IDS:
        data = results["single_env"][env_id]
        assert data["steps_per_s"] == max(data["samples"]) > 0
    for num_envs in map(str, bench.QUICK.vector_num_envs):
        data = results["vector_env"][num_envs]
        assert data["env_steps_per_s"] == max(data["samples"]) > 0
    assert results["ppo"]["snake"]["fps"] > 0
    assert results["ppo"]["torch_threads"] == 1
    for n_links in map(str, bench.QUICK.wheels_links):  # both wheel models, and what one costs against the other
        row = results["wheels"]["links"][n_links]
        assert row["no_slip"] > 0 and row["sliding"] > 0
        assert row["cost_ratio"] == pytest.approx(row["no_slip"] / row["sliding"])
    if results["mujoco"]["available"]:
        assert results["single_env"]["Swimmer-v5"]["steps_per_s"] > 0
        assert results["ppo"]["swimmer"]["fps"] > 0
    else:
        assert any("Swimmer-v5 not measured" in note for note in results["notes"])


def test_udot_covers_every_accepted_method(quick_run):
    from snake_env.dynamics import METHODS

    _, results = quick_run
    series = results["udot"]["seconds_per_call"]
    measured = set(series)
    skipped = set(results["udot"]["skipped_methods"])
    assert measured | skipped >= set(METHODS)
    assert {"kane", "kane_paper", "kane_numpy", "kane_kernel"} <= measured
    for times in series.values():
        assert times and all(t > 0 for t in times.values())


def test_memory_and_startup_numbers_are_sane(quick_run):
    _, results = quick_run
    memory = results["memory"]
    assert memory["num_envs"] == bench.QUICK.memory_num_envs
    assert memory["peak_rss_mb"] >= memory["rss_after_steps_mb"] > 0
    assert memory["peak_rss_mb"] >= memory["rss_after_imports_mb"] > 0
    startup = results["startup"]
    assert 0 < startup["import_and_first_step_s"] <= startup["process_wall_s"]


def test_startup_of_the_no_slip_wheels_is_measured_and_reported():
    """The no-slip wheels' kernels are others than the default sliding ones: the startup section times their
    first step too (here from the current cache; snake-bench's full run from an empty one) and the table names it."""
    from snake_env.benchmarks import bench_sections

    no_slip = bench_sections.startup_time(5, 1, cold=False, env_kwargs={"wheel_model": "no_slip"})
    assert no_slip["env_kwargs"] == {"wheel_model": "no_slip"}
    first = no_slip["first_run"]
    assert 0 < first["import_and_first_step_s"] <= first["plus_vector_first_step_s"]
    rows = bench_report.table_rows({"startup_no_slip": {**no_slip, "cold_start_s": first["plus_vector_first_step_s"]}})
    assert any("wheel_model='no_slip'" in item for _, item, _ in rows)


def test_targets_agree_with_the_measurements(quick_run):
    _, results = quick_run
    targets = {row["key"]: row for row in results["targets"]}
    assert set(targets) == {key for key, *_ in bench_report.TARGETS}
    for row in targets.values():
        assert row["status"] in ("met", "not met", "not measured")
    single = results["single_env"]
    if "Swimmer-v5" in single:
        expected = single[snake_id(3)]["steps_per_s"] / single["Swimmer-v5"]["steps_per_s"]
        assert targets["snake3_vs_swimmer"]["value"] == pytest.approx(expected)
    # quick sizes do not include 1024 envs, n = 1000 or 4096 envs: those are honestly "not measured"
    for key in ("snake5_1024_vs_swimmer", "kane_t1000_over_t100", "kane_paper_over_kane_n200", "snake30_4096_peak_mb"):
        assert targets[key]["status"] == "not measured"
    assert targets["startup_s"]["value"] == results["startup"]["import_and_first_step_s"]


def test_outputs_written_and_markdown_regenerates_from_json(quick_run):
    paths, results = quick_run
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    markdown = paths["markdown"].read_text()
    assert "| section | item | value |" in markdown
    for _, description, _, _ in bench_report.TARGETS:
        assert description in markdown
    assert results["machine"]["cpu"] in markdown
    regenerated = paths["markdown"].parent / "again.md"  # same folder: same relative plot link
    assert bench.main(["--from-json", str(paths["json"]), "--markdown", str(regenerated),
                       "--plot", str(paths["plot"])]) == 0
    assert regenerated.read_text().replace("again.md", "benchmarks.md") == markdown  # the command names the page


def test_regenerating_keeps_the_hand_written_profile(quick_run, tmp_path):
    paths, _ = quick_run
    page = tmp_path / "benchmarks.md"
    profile = f"{bench_report.KEPT_HEADING}: where a step's time goes\n\n- measured by hand\n"
    page.write_text("# Benchmarks\n\nold numbers\n\n" + profile)
    assert bench.main(["--from-json", str(paths["json"]), "--markdown", str(page)]) == 0
    text = page.read_text()
    assert "old numbers" not in text and "| section | item | value |" in text
    assert text.endswith(profile) and text.count(bench_report.KEPT_HEADING) == 1


def _synthetic(swimmer=1000.0, snake3=4500.0, vec1024=110_000.0, t100=1e-5, t1000=2e-4, paper200=1e-3, kane200=1e-5,
               ppo_snake=2000.0, ppo_swimmer=1000.0, peak=499.0, startup=1.0, cold=9.9):
    return {
        "single_env": {"Swimmer-v5": {"steps_per_s": swimmer}, snake_id(3): {"steps_per_s": snake3}},
        "vector_env": {"1024": {"env_steps_per_s": vec1024}},
        "udot": {"seconds_per_call": {"kane": {"100": t100, "200": kane200, "1000": t1000},
                                      "kane_paper": {"200": paper200}}},
        "ppo": {"snake": {"fps": ppo_snake}, "swimmer": {"fps": ppo_swimmer}},
        "memory": {"num_envs": 4096, "peak_rss_mb": peak},
        "startup": {"import_and_first_step_s": startup, "cold_start_s": cold},
    }


def test_target_thresholds_at_their_edges():
    status = {row["key"]: row["status"] for row in bench_report.evaluate_targets(_synthetic())}
    assert status == {
        "snake3_vs_swimmer": "met",  # 4.5 >= 4
        "snake5_1024_vs_swimmer": "not met",  # 110 < 120
        "kane_t1000_over_t100": "not met",  # 20 is not < 15
        "kane_paper_over_kane_n200": "met",  # 100 >= 10
        "ppo_snake5_vs_swimmer": "met",  # exactly 2 counts
        "snake30_4096_peak_mb": "met",  # 499 < 500
        "startup_s": "not met",  # exactly 1 s is not under 1 s
        "cold_start_s": "met",  # 9.9 s < 10 s
    }
    assert bench_report.evaluate_targets(_synthetic(cold=None))[-1]["status"] == "not measured"  # --quick
    empty = bench_report.evaluate_targets({})
    assert all(row["status"] == "not measured" and row["value"] is None for row in empty)


@pytest.mark.parametrize("argv", [["--sections", "single,nope"], ["--plot", "plot.txt"], ["--quick", "--from-json", "x.json"]])
def test_bad_arguments_are_rejected(argv, capsys):
    with pytest.raises(SystemExit) as excinfo:
        bench.main(argv)
    assert excinfo.value.code == 2
    assert "snake-bench: error:" in capsys.readouterr().err


def test_unreadable_json_is_a_clean_error(tmp_path, capsys):
    assert bench.main(["--from-json", str(tmp_path / "missing.json")]) == 2
    assert "--from-json" in capsys.readouterr().err


def test_note_is_kept_in_json_and_page(quick_run, tmp_path):
    paths, _ = quick_run
    saved = tmp_path / "copy.json"
    saved.write_text(paths["json"].read_text())
    page = tmp_path / "page.md"
    assert bench.main(["--from-json", str(saved), "--markdown", str(page), "--note", "measured under load 5"]) == 0
    assert "- measured under load 5" in page.read_text()
    assert "measured under load 5" in json.loads(saved.read_text())["notes"]


def test_without_mujoco_swimmer_is_reported_not_measured(monkeypatch):
    from snake_env.benchmarks import bench_sections

    monkeypatch.setattr(bench_sections, "mujoco_available", lambda: (False, "ModuleNotFoundError: No module named 'mujoco'"))
    results = bench.run_sections(bench.QUICK, ["single"], log=lambda *a, **k: None)
    assert results["errors"] == {}
    assert "Swimmer-v5" not in results["single_env"]
    assert set(results["single_env"]) == set(SNAKE_IDS)
    assert any("No module named 'mujoco'" in note for note in results["notes"])
    status = {row["key"]: row["status"] for row in bench_report.evaluate_targets(results)}
    assert status["snake3_vs_swimmer"] == "not measured"
