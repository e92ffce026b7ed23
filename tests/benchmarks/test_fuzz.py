"""The reduced fuzz of CI: the cells where v0 leaked, through the vector env, leak nothing."""

import json

import numpy as np
import pytest

from snake_env.benchmarks import fuzz


@pytest.mark.parametrize("paper_model", [False, True])
def test_reduced_fuzz_leaks_nothing(paper_model):
    cells = [c for c in fuzz.matrix() if c["paper_model"] == paper_model
             and (c["n_links"], c["max_torque"], c["length"], c["mass"]) in fuzz.QUICK_CELLS]
    assert len(cells) == len(fuzz.QUICK_CELLS)
    rows = [fuzz.run_cell(c, num_envs=32, steps=32 * 60, seed=1) for c in cells]
    ran = [r for r in rows if not r["refused"]]
    assert len(ran) >= 3
    for r in ran:
        # each sim_failure costs one reset step (autoreset) that is not counted
        assert r["env_steps"] + r["sim_failures"] >= 32 * 60
        assert r["leaked"] == 0, r
        assert r["residual_max"] is None or r["residual_max"] <= 1e-2 + 1e-9, r


def test_reduced_fuzz_with_lag_latency_and_randomized_robots_leaks_nothing():
    """The substep-by-substep step (torque lag, latency) and the row-by-row step (randomize) on the cells
    where v0 leaked, with the substeps the env picks: every step reported as valid is finite, balanced
    and unfolded."""
    extra = {"torque_lag": 0.02, "control_latency": 0.02, "randomize": True, "wheel_model": "no_slip"}
    cells = [c for c in fuzz.matrix() if not c["paper_model"]
             and (c["n_links"], c["max_torque"], c["length"], c["mass"]) in fuzz.QUICK_CELLS]
    rows = [fuzz.run_cell({**c, **extra}, num_envs=16, steps=16 * 40, seed=2, auto_substeps=True) for c in cells]
    ran = [r for r in rows if not r["refused"]]
    assert len(ran) == len(cells), [r["note"] for r in rows if r["refused"]]
    for r in ran:
        assert r["env_steps"] + r["sim_failures"] >= 16 * 40
        assert r["leaked"] == 0, r
        assert r["residual_max"] is None or r["residual_max"] <= 1e-2 + 1e-9, r


@pytest.mark.parametrize("extra, num_envs, seed", [
    ({"rotor_inertia": 0.005, "wheel_model": "no_slip"}, 32, 3),  # the motors' rotors, a Dynamixel's order (kg m^2)
    ({"rotor_inertia": 0.005}, 16, 5),  # the same on the default sliding wheels (their null-space solve)
    ({"wheel_model": "no_slip"}, 32, 4),  # v3's no-slip wheels under the traction limit (the default slides)
    ({"torque_lag": 0.02, "control_latency": 0.02}, 16, 6),  # the motor's response in time on the sliding wheels
    ({"torque_lag": 0.02, "randomize": True}, 16, 7),  # randomized robots on the sliding wheels, latency drawn
])
def test_reduced_fuzz_with_rotors_or_either_wheels_leaks_nothing(extra, num_envs, seed):
    """Rotor inertia on either wheels, the no-slip wheels (the test above runs the default sliding ones), and a
    torque lag and latency or randomized robots on the sliding wheels (substep by substep, row by row), on
    the cells where v0 leaked, with the substeps the env picks: every step reported as valid is finite, balanced
    and unfolded."""
    cells = [c for c in fuzz.matrix() if not c["paper_model"]
             and (c["n_links"], c["max_torque"], c["length"], c["mass"]) in fuzz.QUICK_CELLS]
    rows = [fuzz.run_cell({**c, **extra}, num_envs=num_envs, steps=num_envs * 40, seed=seed, auto_substeps=True)
            for c in cells]
    assert not any(r["refused"] for r in rows), [r["note"] for r in rows if r["refused"]]
    for r in rows:
        assert r["env_steps"] + r["sim_failures"] >= num_envs * 40
        assert r["leaked"] == 0, r
        assert r["residual_max"] is None or r["residual_max"] <= 1e-2 + 1e-9, r


def test_fuzz_cli_writes_the_report(tmp_path):
    md, js = tmp_path / "reliability.md", tmp_path / "fuzz.json"
    code = fuzz.main(["--steps-per-cell", "64", "--num-envs", "16", "--only", "'n_links': 3, 'max_torque': 10.0, "
                      "'length': 0.2, 'mass': 1.0", "--json", str(js), "--markdown", str(md)])
    assert code == 0
    rows = json.loads(js.read_text())
    assert len(rows) == 2 and all(r["leaked"] == 0 for r in rows)
    text = md.read_text()
    assert "Leaked values: 0" in text and "| 3 | 10 | 0.2 | 1 |" in text


def test_fuzz_cli_rejects_bad_sizes(capsys):
    with pytest.raises(SystemExit) as exc:
        fuzz.main(["--num-envs", "1"])
    assert exc.value.code == 2
    assert "--num-envs" in capsys.readouterr().err


def test_a_time_capped_cell_stops_early_and_says_how_far_it_got():
    cell = next(c for c in fuzz.matrix() if (c["n_links"], c["max_torque"], c["length"], c["mass"]) == (5, 1.0, 0.2, 1.0))
    row = fuzz.run_cell(cell, num_envs=16, steps=16 * 10 ** 6, seed=0, max_seconds=0.2)
    assert 0 < row["env_steps"] < 16 * 10 ** 6 and row["leaked"] == 0


def test_fuzz_cli_rejects_a_non_positive_time_cap(capsys):
    with pytest.raises(SystemExit) as exc:
        fuzz.main(["--seconds-per-cell", "0"])
    assert exc.value.code == 2
    assert "--seconds-per-cell" in capsys.readouterr().err


def test_shards_split_the_matrix_by_setting_and_join_into_one_report(tmp_path):
    only = "'n_links': 2, 'max_torque': 0.1, 'length': 1.0"  # 3 masses x paper off/on: 6 cells
    parts = []
    for index in range(2):
        js = tmp_path / f"shard{index}.json"
        assert fuzz.main(["--steps-per-cell", "32", "--num-envs", "16", "--only", only, "--shard", f"{index}/2",
                          "--json", str(js)]) == 0
        parts.append(json.loads(js.read_text()))
    # a setting's two cells (paper_model off, on) stay in one shard; the shards are disjoint and cover it
    assert [len(p) for p in parts] == [4, 2]
    for part in parts:
        assert [r["paper_model"] for r in part] == [False, True] * (len(part) // 2)
    masses = [{r["mass"] for r in p} for p in parts]
    assert masses[0].isdisjoint(masses[1]) and masses[0] | masses[1] == {0.05, 1.0, 20.0}
    md = tmp_path / "reliability.md"
    assert fuzz.main(["--from-json", str(tmp_path / "shard1.json"), str(tmp_path / "shard0.json"),
                      "--markdown", str(md)]) == 0
    rows = [line for line in md.read_text().splitlines() if line.startswith("| 2 | 0.1 | 1 |")]
    assert [line.split(" | ")[3:5] for line in rows] == [[m, p] for m in ("0.05", "1", "20") for p in ("no", "yes")]


@pytest.mark.parametrize("shard", ["2/2", "1", "a/2", "0/0", "-1/2"])
def test_fuzz_cli_rejects_a_bad_shard(capsys, shard):
    with pytest.raises(SystemExit) as exc:
        fuzz.main([f"--shard={shard}"])
    assert exc.value.code == 2
    assert "--shard must be I/K" in capsys.readouterr().err


def test_resume_runs_only_the_short_cells_with_a_new_seed_and_the_parts_join(tmp_path, capsys):
    only = "'n_links': 3, 'max_torque': 1.0, 'length': 1.0, 'mass': 1.0"  # paper_model off and on
    first, second, md = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "reliability.md"
    assert fuzz.main(["--steps-per-cell", "64", "--num-envs", "16", "--only", only, "--json", str(first)]) == 0
    rows = json.loads(first.read_text())
    assert len(rows) == 2 and all(r["env_steps"] >= 64 for r in rows)
    # a cell already at --steps-per-cell is skipped; the short ones run for what they lack
    common = ["--num-envs", "16", "--only", only, "--resume", str(first), "--json", str(second)]
    assert fuzz.main(["--steps-per-cell", "64", "--seed", "1"] + common) == 0
    assert json.loads(second.read_text()) == []
    assert fuzz.main(["--steps-per-cell", "160", "--seed", "0"] + common) == 2  # same trajectories again
    assert "--seed 0 already ran cell" in capsys.readouterr().err
    assert fuzz.main(["--steps-per-cell", "160", "--seed", "1"] + common) == 0
    # the resumed run may order its cells differently (by the time each lacks): pair them by cell
    by_cell = {fuzz.cell_key(r): r for r in json.loads(second.read_text())}
    added = [by_cell[fuzz.cell_key(r)] for r in rows]
    assert [r["seed"] for r in added] == [1, 1]
    assert all(160 - a["env_steps"] <= r["env_steps"] for r, a in zip(added, rows))
    joined = fuzz.join_rows(rows + added)
    for j, a, b in zip(joined, rows, added):
        assert j["seed"] == [0, 1] and j["env_steps"] == a["env_steps"] + b["env_steps"] >= 160
        assert j["sim_failures"] == a["sim_failures"] + b["sim_failures"] and j["leaked"] == 0
        assert j["residual_max"] == max(a["residual_max"], b["residual_max"])
        assert sum(j["residual_histogram"]) == sum(a["residual_histogram"]) + sum(b["residual_histogram"])
    # a joined report (seeds as lists) joins again with a later part, and still refuses a seed twice
    later = [dict(b, seed=2) for b in added]
    again = fuzz.join_rows(joined + later)
    assert [r["seed"] for r in again] == [[0, 1, 2]] * 2
    assert [r["env_steps"] for r in again] == [j["env_steps"] + b["env_steps"] for j, b in zip(joined, added)]
    with pytest.raises(ValueError, match="each part of a cell needs its own --seed"):
        fuzz.join_rows(joined + added)
    assert fuzz.main(["--from-json", str(first), str(second), "--markdown", str(md)]) == 0
    text = md.read_text()
    assert "2 cells ran in more than one part" in text
    assert f"| {joined[0]['env_steps']:,} |" in text
    with pytest.raises(ValueError, match="each part of a cell needs its own --seed"):
        fuzz.join_rows(rows + rows)
    assert fuzz.main(["--from-json", str(first), str(first)]) == 2


def test_the_histogram_median_is_within_its_bin_of_the_exact_median():
    cell = next(c for c in fuzz.matrix() if (c["n_links"], c["max_torque"], c["length"], c["mass"], c["paper_model"])
                == (5, 1.0, 0.2, 1.0, True))
    row = fuzz.run_cell(cell, num_envs=16, steps=16 * 40, seed=0)
    assert sum(row["residual_histogram"]) > 0
    ratio = fuzz.histogram_median(row["residual_histogram"]) / row["residual_median"]
    assert 10 ** (-1 / fuzz.RESIDUAL_BINS_PER_DECADE) <= ratio <= 10 ** (1 / fuzz.RESIDUAL_BINS_PER_DECADE)


def test_the_report_names_its_command_without_the_note_texts(tmp_path):
    js, md = tmp_path / "fuzz.json", tmp_path / "reliability.md"
    assert fuzz.main(["--steps-per-cell", "32", "--num-envs", "16", "--only", "'n_links': 2, 'max_torque': 0.1, "
                      "'length': 1.0, 'mass': 1.0", "--json", str(js)]) == 0
    assert fuzz.main(["--from-json", str(js), "--note", "ran on a laptop", "--note=twice", "--markdown", str(md)]) == 0
    text = md.read_text()
    assert f"Generated by `python -m snake_env.benchmarks.fuzz --from-json {js} --markdown {md}`" in text
    assert "- ran on a laptop\n- twice\n" in text


def test_resume_runs_the_cheapest_cells_first_and_a_budget_ends_the_run(tmp_path, capsys):
    only = "'n_links': 3, 'max_torque': 1.0, 'length': 1.0, 'mass': 1.0"  # paper_model off and on
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    assert fuzz.main(["--steps-per-cell", "32", "--num-envs", "16", "--only", only, "--json", str(first)]) == 0
    rows = json.loads(first.read_text())
    assert [r["paper_model"] for r in rows] == [False, True]
    # make the paper_model cell the one that lacks the fewest seconds: it must run first
    rows[0]["seconds"], rows[1]["seconds"] = 1000.0, 0.001
    first.write_text(json.dumps(rows))
    common = ["--steps-per-cell", "10000000", "--num-envs", "16", "--only", only, "--resume", str(first), "--seed", "1",
              "--json", str(second)]
    assert fuzz.main(common + ["--budget-s", "0.3"]) == 0
    added = json.loads(second.read_text())
    # the budget ended the first cell early and the second never started
    assert [r["paper_model"] for r in added] == [True]
    assert 0 < added[0]["env_steps"] < 10000000 - rows[1]["env_steps"]
    assert "--budget-s 0.3 spent" in capsys.readouterr().out


def test_fuzz_cli_rejects_a_non_positive_budget(capsys):
    with pytest.raises(SystemExit) as exc:
        fuzz.main(["--budget-s", "-1"])
    assert exc.value.code == 2
    assert "--budget-s must be > 0" in capsys.readouterr().err


@pytest.mark.parametrize("n_links, max_torque, length, mass", [(2, 10.0, 0.02, 0.05), (5, 1.0, 0.2, 1.0),
                                                               (30, 0.1, 0.02, 0.05)])
def test_the_fold_time_bounds_the_first_fold_from_rest(n_links, max_torque, length, mass):
    """The report's fold time is a lower bound: the paper model at rest, driven by the maximum
    torque with alternating signs, folds no sooner (resolved to 1/200 of the bound)."""
    from snake_env import physics
    from snake_env.physics.config import PhysicsConfig

    inertia = mass * length ** 2 / 12.0
    bound = fuzz.fold_time({"inertia": inertia, "max_torque": max_torque})
    _, params = PhysicsConfig(n_links=n_links, max_torque=max_torque, length=length, mass=mass, inertia=inertia,
                              paper_model=True, sim_dt=bound / 200.0, frame_skip=1).build()
    q, u, _, _ = physics.reset(params, np.zeros(n_links + 2))
    torques = max_torque * (-1.0) ** np.arange(n_links - 1)
    for step in range(1, 20 * 200):
        q, u, _, aux = physics.step(params, q, u, torques)
        if aux[physics.AUX_FAILED]:
            break
    assert aux[physics.AUX_FAILED] == physics.FAIL_FOLD
    assert step * params.sim_dt >= bound
    if n_links == 2:  # inertia m L^2 / 12: the effective joint inertia is 2.25^2 times the bound's I / 2
        assert step * params.sim_dt == pytest.approx(2.25 * bound, rel=0.01)


def test_the_report_classes_the_paper_cells_by_fold_time():
    rows = [{"refused": False, "paper_model": paper, "inertia": inertia, "max_torque": 1.0, "env_steps": 100,
             "sim_failures": failures} for paper, inertia, failures in
            [(True, 1e-6, 90), (True, 2e-6, 50), (True, 1.0, 1), (False, 1e-6, 0)]]
    classes = {fuzz.fold_time(r) / fuzz.ENV_DT < 0.3 for r in rows[:3]}
    assert classes == {True, False}
    table = fuzz.fold_time_table(rows)
    assert "| < 0.3 | 2 | 70.0% | 90.0% |" in table
    assert sum(line.split(" | ")[1] == "1" for line in table[2:]) == 1  # the slow-folding cell, alone in its class
