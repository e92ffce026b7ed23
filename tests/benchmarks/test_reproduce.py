"""snake-reproduce --quick writes every file, with the numbers the report cites."""

import json
import os
import subprocess
import sys

import pytest

from snake_env.benchmarks import reproduce
from snake_env.atomic import _file_mode


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    assert reproduce.main(["--out", str(out), "--quick"]) == 0
    return out


def test_quick_run_writes_every_file(quick_run):
    for name in reproduce.OUTPUT_FILES:
        path = quick_run / name
        assert path.is_file() and path.stat().st_size > 0, name
    for name in reproduce.OUTPUT_FILES:
        if name.endswith(".png"):
            assert (quick_run / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in os.listdir(quick_run) if p.startswith(".")]  # no temp file left behind
    # atomic writes keep the permissions a plain open() would give, not mkstemp's 0o600
    assert all((quick_run / name).stat().st_mode & 0o777 == _file_mode() for name in reproduce.OUTPUT_FILES)


def test_report_answers_the_four_claims(quick_run):
    report = (quick_run / "report.md").read_text()
    for heading in ("## 1. Number of operations", "## 2. CPU time", "## 3. Precision", "## 4. Energy error"):
        assert heading in report
    assert report.count("Verdict:") == 4
    results = json.loads((quick_run / "results.json").read_text())
    ops = results["operation_counts"]
    assert {m: v["degree"] for m, v in ops.items()} == {"kane_paper": 2, "kane": 1, "lagrange": 3, "newton_euler": 3}
    assert ops["lagrange"]["M"] in report  # the report quotes the counted polynomial
    energy = results["accuracy"]["energy"]
    # Lagrange's udot integrated in u-space follows the very same trajectory as Kane
    assert energy["lagrange_u_space"]["max_abs_energy_error_J"] == pytest.approx(
        energy["kane"]["max_abs_energy_error_J"], rel=1e-3)
    table1 = (quick_run / "table1.md").read_text()
    assert "paper, printed" in table1 and "inconsistencies" in table1


def test_cli_entry_point_rejects_bad_arguments(tmp_path):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    with pytest.raises(SystemExit) as exc:
        reproduce.main(["--out", str(a_file), "--quick"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit):
        reproduce.main(["--quick"])  # --out is required


def test_module_runs_as_a_script_help():
    proc = subprocess.run([sys.executable, "-m", "snake_env.benchmarks.reproduce", "--help"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0 and "--quick" in proc.stdout
