"""The sliding-step profile tool runs, its parts add up, and it rejects bad input with one line (its timings
are not asserted)."""

import pytest

from snake_env.benchmarks import sliding_step_profile


def test_the_profile_splits_the_step(capsys):
    assert sliding_step_profile.main(["--envs", "3", "--steps", "2"]) == 0
    rows = dict(line.split(": ", 1) for line in capsys.readouterr().out.splitlines())
    assert rows["substeps"] == "40"  # 1 ms substeps over the 40 ms control step
    step, kernel = float(rows["env step (us)"]), float(rows["row kernel (us)"])
    assert 0.0 < kernel < step  # the timed kernel is a part of the timed step
    replay = dict(item.split(": ") for item in rows["replay (us per row)"].split(", "))
    assert list(replay) == [str(count) for count in sliding_step_profile.REPLAY_SUBSTEPS]
    assert all(float(value) > 0.0 for value in replay.values())


@pytest.mark.parametrize("env_id, says", [("snake_env/Nope-v0", "doesn't exist"),
                                          ("snake_env/Snake5-v3", "needs the sliding wheels")])
def test_an_unknown_or_no_slip_env_is_one_line_and_exit_2(capsys, env_id, says):
    assert sliding_step_profile.main(["--env", env_id, "--envs", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"sliding_step_profile: error: --env '{env_id}': ") and says in err[0]


def test_a_bad_count_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as excinfo:
        sliding_step_profile.main(["--steps", "0"])
    assert excinfo.value.code == 2
    assert "--steps must be an integer >= 1, got 0" in capsys.readouterr().err
