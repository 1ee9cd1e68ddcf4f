"""scripts/setup: the main job's set-up installs no system package, and a system package that cannot be
installed (the package manager locked, no network) never fails a set-up.

The script runs as it is, copied beside a stand-in ``.venv/bin/python`` (which records the pip calls) and
a stand-in ``apt-get`` (which records its calls and fails as a locked dpkg does, exit 100).
"""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _sandbox(tmp_path):
    (tmp_path / "scripts").mkdir()
    shutil.copy(ROOT / "scripts" / "setup", tmp_path / "scripts" / "setup")
    bin_dir = tmp_path / "bin"
    venv = tmp_path / ".venv" / "bin"
    for d in (bin_dir, venv):
        d.mkdir(parents=True)
    calls = tmp_path / "calls.log"
    (venv / "python").write_text(f'#!/bin/sh\necho "python $*" >> {calls}\n')
    (bin_dir / "apt-get").write_text(f'#!/bin/sh\necho "apt-get $*" >> {calls}\n'
                                     'echo "E: Could not get lock /var/lib/dpkg/lock-frontend" >&2\nexit 100\n')
    (bin_dir / "id").write_text("#!/bin/sh\necho 0\n")  # root, so the script tries apt-get
    for f in (venv / "python", bin_dir / "apt-get", bin_dir / "id"):
        f.chmod(0o755)
    # a PATH without /usr/local/bin, where a host may link initdb
    env = {**os.environ, "PATH": f"{bin_dir}:/usr/bin:/bin",
           "SETUP_INITDB_GLOB": str(tmp_path / "no-postgresql" / "initdb"),
           "SETUP_CHROMIUM": str(tmp_path / "no-chromium")}
    return env, calls


def _setup(tmp_path, env, *args):
    return subprocess.run(["bash", str(tmp_path / "scripts" / "setup"), *args], env=env, capture_output=True,
                          text=True, timeout=60)


def test_the_main_jobs_setup_installs_no_system_package(tmp_path):
    env, calls = _sandbox(tmp_path)
    done = _setup(tmp_path, env)
    assert done.returncode == 0, done.stderr
    log = calls.read_text()
    assert "apt-get" not in log
    assert "pip install -q -e ." in log and "[test]" not in log


def test_a_locked_package_manager_does_not_fail_the_tests_setup(tmp_path):
    if shutil.which("initdb", path="/usr/bin:/bin"):
        pytest.skip("initdb in /usr/bin: the script would not look for the PostgreSQL package")
    env, calls = _sandbox(tmp_path)
    done = _setup(tmp_path, env, "--tests")
    assert done.returncode == 0, done.stderr
    log = calls.read_text()
    assert "pip install -q -e .[test]" in log
    assert log.count("apt-get -o DPkg::Lock::Timeout=") == 2  # both were tried, each waiting for the lock
    failed = [line for line in done.stderr.splitlines() if "could not install" in line]
    assert len(failed) == 2 and "PostgreSQL" in failed[0] and "chromium" in failed[1], done.stderr


def test_setup_refuses_an_unknown_option(tmp_path):
    env, _ = _sandbox(tmp_path)
    done = _setup(tmp_path, env, "--test")
    assert done.returncode == 2 and "unknown option --test" in done.stderr
