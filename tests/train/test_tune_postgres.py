"""Two snake-tune workers on one study in a real PostgreSQL server that this test starts.

The server is made with ``initdb`` + ``pg_ctl`` in a temporary directory. PostgreSQL
refuses to run as root, so as root (CI) the server runs as the unprivileged user
``nobody`` through ``runuser``; as another user it runs as that user.
Skipped only when no PostgreSQL binaries are installed (``.ci/run`` installs
Debian's ``postgresql`` package).
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState

from tests.train.test_tune import tune_args, worker

PG_USER = "snake"


def postgres_bin_dir() -> Path | None:
    """A directory with initdb and pg_ctl: PATH first, then Debian's /usr/lib/postgresql/<version>/bin."""
    initdb = shutil.which("initdb")
    if initdb and shutil.which("pg_ctl"):
        return Path(initdb).resolve().parent
    for directory in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True):
        if (Path(directory) / "initdb").is_file() and (Path(directory) / "pg_ctl").is_file():
            return Path(directory)
    return None


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="module")
def postgres_url():
    bin_dir = postgres_bin_dir()
    if bin_dir is None:
        pytest.skip("no PostgreSQL binaries (initdb, pg_ctl) on PATH or in /usr/lib/postgresql/*/bin; "
                    "install Debian's postgresql package (.ci/run does)")
    as_root = os.geteuid() == 0
    if as_root and shutil.which("runuser") is None:
        pytest.skip("running as root and no runuser to start PostgreSQL as an unprivileged user")
    base = Path(tempfile.mkdtemp(prefix="snake-tune-pg-"))
    data = base / "data"
    data.mkdir()
    prefix = []
    if as_root:
        nobody = pwd.getpwnam("nobody")
        base.chmod(0o755)  # the server user must reach its data directory
        os.chown(data, nobody.pw_uid, nobody.pw_gid)
        prefix = ["runuser", "-u", "nobody", "--"]
    port = free_port()

    def pg(*command, **kwargs):
        return subprocess.run([*prefix, *command], cwd=base, check=True, capture_output=True, text=True,
                              timeout=120, **kwargs)

    pg(str(bin_dir / "initdb"), "-D", str(data), "-U", PG_USER, "--auth=trust", "-E", "UTF8", "--no-sync")
    options = f"-p {port} -k {data} -c listen_addresses=127.0.0.1 -c fsync=off"
    pg(str(bin_dir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(data / "server.log"), "-w", "start")
    try:
        yield f"postgresql+psycopg://{PG_USER}@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run([*prefix, str(bin_dir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"], cwd=base,
                       capture_output=True, timeout=120)
        shutil.rmtree(base, ignore_errors=True)


def test_two_workers_share_one_postgresql_study(tmp_path, postgres_url):
    args = ["--storage", postgres_url, "--pruner", "none", "--study-name", "two-workers"]
    workers = [worker(tune_args(tmp_path / f"worker{k}", 256, 2, *args)) for k in range(2)]
    results = []
    deadline = time.monotonic() + 600
    for process in workers:
        results.append(process.communicate(timeout=max(1.0, deadline - time.monotonic())))
    for process, (stdout, stderr) in zip(workers, results):
        assert process.returncode == 0, stderr
        assert stdout.count("COMPLETE") >= 2
    study = optuna.load_study(study_name="two-workers", storage=postgres_url)
    trials = study.trials
    assert len(trials) == 4
    assert all(t.state == TrialState.COMPLETE for t in trials)
    assert sorted(t.number for t in trials) == [0, 1, 2, 3]  # distinct numbers across both workers
    assert all((tmp_path / f"worker{k}" / "best_config.yaml").is_file() for k in range(2))
    assert not (tmp_path / "worker0" / "study.db").exists()  # the study lives in PostgreSQL
