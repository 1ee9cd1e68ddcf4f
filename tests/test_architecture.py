"""The direction of dependencies holds by construction (contracts in pyproject.toml)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")


def _lint(cwd: Path, pythonpath: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(pythonpath)}
    return subprocess.run([LINT, str(cwd / "pyproject.toml")], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def _copy_code(dst: Path) -> None:
    for pkg in ("app", "station", "drivers", "fakes", "procedures"):
        shutil.copytree(ROOT / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", dst / "pyproject.toml")


@pytest.fixture(scope="module")
def lint():
    if LINT is None:
        pytest.fail("lint-imports is not installed (it is in the test extra: pip install -e '.[test]')")
    return _lint


def test_the_import_contracts_hold(lint):
    res = lint(ROOT, ROOT)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    assert "0 broken" in res.stdout


LAYERS = "Layers from the roof down"


@pytest.mark.parametrize("importer, imported, contract", [
    ("station/models/leak.py", "fakes.sim", LAYERS),
    ("station/analysis/leak.py", "procedures.execute", LAYERS),
    # a core module that no contract names, in a package that did not exist before
    ("station/newroom/leak.py", "procedures.execute", LAYERS),
    ("station/readers/leak.py", "app.cli", LAYERS),
    ("station/leak.py", "drivers.tracker", LAYERS),
    ("drivers/leak.py", "fakes.sim", LAYERS),
    ("drivers/leak.py", "procedures.execute", LAYERS),
    ("fakes/leak.py", "drivers.tracker", LAYERS),
    ("fakes/leak.py", "procedures.registry", LAYERS),
    ("procedures/leak.py", "app.assemble", LAYERS),
    ("procedures/leak.py", "fakes.sim", "Procedures never import fakes"),
])
def test_a_forbidden_import_breaks_the_contracts(lint, tmp_path, importer, imported, contract):
    """The same contracts on a copy of the code with one forbidden import added."""
    _copy_code(tmp_path)
    folder = (tmp_path / importer).parent
    folder.mkdir(exist_ok=True)
    if not (folder / "__init__.py").exists():
        (folder / "__init__.py").write_text("")
    (tmp_path / importer).write_text(f"import {imported}\n")
    res = lint(tmp_path, tmp_path)
    assert res.returncode != 0
    assert contract in res.stdout and "BROKEN" in res.stdout, res.stdout[-2000:]


def test_an_import_cycle_breaks_the_contracts(lint, tmp_path):
    _copy_code(tmp_path)
    (tmp_path / "procedures" / "a.py").write_text("import procedures.b\n")
    (tmp_path / "procedures" / "b.py").write_text("def f():\n    import procedures.a\n")
    res = lint(tmp_path, tmp_path)
    assert res.returncode != 0 and "No import cycles" in res.stdout, res.stdout[-2000:]


def test_every_tracker_driver_offers_the_tracker_interface():
    """Devices have one interface style: a Protocol the procedures see, drivers implementing it (the
    trackers on a shared base class); a tracker driver missing a method of the interface is caught here."""
    import inspect
    import typing

    from drivers.emscon import EmsconTracker
    from drivers.geocom import GeoComTracker
    from drivers.robot import Robot
    from drivers.tracker import Tracker, TrackerBase

    assert typing.Protocol in Tracker.__mro__ and typing.Protocol in Robot.__mro__
    wanted = {n for n, v in vars(Tracker).items() if inspect.isfunction(v) and not n.startswith("_")}
    assert {"connect", "measure_stationary", "start_stream", "stop_stream", "read_samples", "close"} <= wanted
    for cls in (EmsconTracker, GeoComTracker):
        assert issubclass(cls, TrackerBase)
        missing = {n for n in wanted if getattr(cls, n, None) is None or getattr(getattr(cls, n), "__isabstractmethod__", False)}
        assert not missing, f"{cls.__name__} lacks {sorted(missing)}"
    assert inspect.isabstract(TrackerBase)
