"""speed_vs_n.png's CSV inputs (--earlier, --measured) of snake_env.train.results_table."""

from snake_env.train.results_table import speeds_from_csv


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
