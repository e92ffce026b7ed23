"""The single-env profile tool runs and rejects bad input with one line (its timings are not asserted)."""

import math

import pytest

from snake_env.benchmarks import single_step_profile


def test_the_profile_prints_every_part(capsys):
    assert single_step_profile.main(["--calls", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[:2] == ["| part of one step | us |", "|---|---|"]
    rows = dict(line.strip("| ").split(" | ") for line in lines[2:])
    assert list(rows)[0] == "the whole step through gym.make's wrappers"
    assert "the compiled kernel alone, through numba's dispatcher" in rows
    assert len(rows) == 10 and all(math.isfinite(float(value)) for value in rows.values())


def test_an_unknown_env_is_one_line_and_exit_2(capsys):
    assert single_step_profile.main(["--env", "snake_env/Nope-v0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("single_step_profile: error: --env 'snake_env/Nope-v0': ")


def test_a_bad_call_count_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as excinfo:
        single_step_profile.main(["--calls", "0"])
    assert excinfo.value.code == 2
    assert "--calls must be a positive integer, got 0" in capsys.readouterr().err
