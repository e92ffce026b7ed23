"""snake_env.train.results_table: speed_vs_n.png's CSV inputs (--earlier, --measured) and the tables."""

import numpy as np

from snake_env.train.aggregate import iqm
from snake_env.train.results_table import print_tables, speeds_from_csv


def test_speeds_from_csv_groups_the_snake_n_rows_by_algo_and_n(tmp_path):
    path = tmp_path / "speeds.csv"
    path.write_text("env,algo,seed,speed,note\n"
                    "Snake20-v2,sac,0,0.231,a\nSnake20-v2,sac,1,0.221,b\nSnake5-v2,ppo,0,5.2,c\n"
                    "Snake-v2,ppo,0,5.1,default n: no size\nSnakePath8-v2,sac,0,2.1,a task\n")
    speeds = speeds_from_csv(path, "this table")
    assert dict(speeds[("sac", "SAC (this table)")]) == {20: [0.231, 0.221]}
    assert dict(speeds[("ppo", "PPO (this table)")]) == {5: [5.2]}
    assert len(speeds) == 2
    # --measured adds to the runs found under root
    learned = speeds_from_csv(path, "this table")
    speeds_from_csv(path, "this table", into=learned)
    assert learned[("sac", "SAC (this table)")][20] == [0.231, 0.221, 0.231, 0.221]


def _run(seed, speed, **gait):
    det = {"mean_forward_velocity": speed, "std_forward_velocity": 0.01, "mean_return": 1000 * speed,
           "std_return": 1.0, **gait}
    return {"seed": seed, "steps": 1000, "wall": 60.0 * (seed + 1), "det": det,
            "sto": {"mean_forward_velocity": speed / 2}, "best": None}


def test_tables_give_the_iqm_of_each_id_and_of_all_ids_then_every_seed(capsys, monkeypatch):
    monkeypatch.setattr("snake_env.train.aggregate.BOOTSTRAP_REPS", 1000)  # the same in the table and here
    speeds = {"Snake12-v3": [0.6, 0.7, 0.3, 0.65, 0.72], "Snake3-v3": [1.4, 1.5, 1.45, 1.46, 1.47]}
    runs = {(env, "ppo"): [_run(s, v, mean_dominant_joint_frequency=2.5) for s, v in enumerate(values)]
            for env, values in speeds.items()}
    baselines = {"Snake12-v3": {"mean_forward_velocity": 0.4}, "Snake3-v3": {"mean_forward_velocity": 1.25}}
    print_tables(runs, baselines)
    out = capsys.readouterr().out.splitlines()
    rows = [line for line in out if line.startswith("| Snake")]
    assert rows[0].startswith("| Snake3-v3 | 0, 1, 2, 3, 4 |")  # sorted by n, not by name
    assert f"| {iqm(np.array(speeds['Snake12-v3']) / 0.4)} |" in rows[1]
    assert "| 0.75 | 4 of 5 | 0.400 | 3.0 |" in rows[1]  # lowest ratio, seeds >= 0.8x, serpenoid, median wall
    matrix = np.stack([np.array(speeds["Snake12-v3"]) / 0.4, np.array(speeds["Snake3-v3"]) / 1.25], axis=1)
    assert any(line.startswith(f"| all 2 ids | 5 per id | | {iqm(matrix)} |") for line in out)
    per_seed = [line for line in rows if "| PPO |" in line]
    assert len(per_seed) == 10 and per_seed[0].startswith("| Snake3-v3 | PPO | 0 |")
    assert per_seed[-1].endswith("| 2.50 | - | - |")  # gait metrics the eval lacks are "-"


def test_a_length_with_no_id_is_evaluated_on_the_generic_id():
    import snake_env  # noqa: F401
    from snake_env.train.results_table import env_arguments

    assert env_arguments("snake_env/Snake12-v3") == ["--env", "snake_env/Snake12-v3"]
    assert env_arguments("snake_env/Snake10-v3") == ["--env", "snake_env/Snake-v3", "--env-kwarg", "n_links=10"]


def test_a_csv_row_may_name_its_curve(tmp_path):
    path = tmp_path / "speeds.csv"
    path.write_text("env,algo,seed,speed,label\nSnake20-v3,jointpolicy,0,0.17,JointPolicy zero-shot\n"
                    "Snake5-v3,ppo,0,1.3,\n")
    speeds = speeds_from_csv(path, "this table")
    assert dict(speeds[("jointpolicy", "JointPolicy zero-shot")]) == {20: [0.17]}
    assert dict(speeds[("ppo", "PPO (this table)")]) == {5: [1.3]}


def test_the_serpenoid_is_drawn_on_the_versions_of_the_measured_csv(tmp_path):
    from snake_env.train.results_table import csv_versions

    path = tmp_path / "speeds.csv"
    path.write_text("env,algo,seed,speed\nSnake12-v3,ppo,0,0.9\nSnake16-v3,joint,0,0.4\nSnakePath5-v2,ppo,0,1.0\n")
    assert csv_versions(path) == {"v3"}  # tasks and the generic id do not count
    assert csv_versions(None) == set()
