"""The README's first hour, literally: every line of its newcomer block in a fresh directory, each exit 0.

The block is read from README.md (after the ``<!-- newcomer-path -->`` marker), so the README and what
works cannot drift apart. ``station`` is the set-up's ``.venv/bin/station`` put on PATH, as the README says.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def newcomer_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    m = re.search(r"<!-- newcomer-path -->\s*```bash\n(.*?)```", text, re.S)
    assert m, "README.md has no newcomer block"
    lines = [line.split("#", 1)[0].strip() for line in m.group(1).splitlines()]
    return [line for line in lines if line]


def test_the_readme_newcomer_path_runs_in_a_fresh_directory(tmp_path):
    cmds = newcomer_commands()
    assert cmds[0] == "station init" and any(c.startswith("station simulate arm") for c in cmds)
    for kind in ("iso9283", "arm", "trailer"):
        assert any(c.startswith(f"station simulate {kind}") for c in cmds), kind
    for cmd in ("analyze iso9283", "analyze hold", "calibrate arm", "diagnose arm", "calibrate trailer",
                "diagnose trailer"):
        assert any(c.startswith(f"station {cmd}") for c in cmds), cmd
    bindir = Path(sys.executable).parent
    assert (bindir / "station").exists()
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    for cmd in cmds:
        out = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, f"{cmd}: exit {out.returncode}\n{out.stdout[-1500:]}\n{out.stderr[-1500:]}"
    for f in ("station.toml", "iso/stream.csv", "arm/arm.csv", "arm/truth.json", "trailer/trailer.csv",
              "hold/stream.csv", "iso/result.json", "arm/calibration.json"):
        assert (tmp_path / f).exists(), f
    assert list((tmp_path / "reports").glob("*.frame.json"))
