"""Cut a dry run several times in a row (SIGINT or SIGKILL at random moments), resume it each time, and
compare it with the same seed left alone. Run by hand::

    .venv/bin/python bench/bench_resume_cuts.py [--seed S] [--cuts 3] [--cycles 6] [--time-scale 20]

Prints, for each cut, the signal and the step it hit, then per pose the cycle
counts and |dAP|, |dRP| against the uninterrupted run (mm), and the largest.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fakes.cells import demo_config  # noqa: E402


def station(*args):
    return [sys.executable, "-m", "app.cli", *args]


def table(path: Path) -> dict:
    return {(c["pose"], c["name"]): c["value"] for c in json.loads(path.read_text())["characteristics"]}


def running_step(db: Path, run_id: str) -> str:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
    try:
        row = con.execute("SELECT name FROM steps WHERE run_id=? ORDER BY started_at DESC LIMIT 1", (run_id,)).fetchone()
    except sqlite3.OperationalError:
        row = None
    finally:
        con.close()
    return row[0] if row else "-"


def recorded(out: Path) -> bool:
    con = sqlite3.connect(out / "station.sqlite")
    try:
        return bool(con.execute("SELECT COUNT(*) FROM runs WHERE run_id='cut'").fetchone()[0])
    finally:
        con.close()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--cuts", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=6)
    ap.add_argument("--vap-cycles", type=int, default=3)
    ap.add_argument("--time-scale", default="20")
    args = ap.parse_args()
    seed = int(np.random.default_rng().integers(0, 2**31)) if args.seed is None else args.seed
    rng = np.random.default_rng(seed)
    print(f"seed {seed}")
    out = Path(tempfile.mkdtemp(prefix="resume-cuts-"))
    cfg = out / "station.json"
    cfg.write_text(json.dumps(demo_config(out, cycles=args.cycles, vap_cycles=args.vap_cycles, rate_hz=100.0)))
    common = ["--config", str(cfg), "--yes", "--quiet"]
    t0 = time.monotonic()
    ref = subprocess.run(station("run", "iso9283", "--run-id", "ref", "--seed", str(seed), "--time-scale",
                                 args.time_scale, "--json", str(out / "ref.json"), *common), cwd=ROOT,
                         capture_output=True, text=True)
    wall = time.monotonic() - t0
    print(f"uninterrupted: exit {ref.returncode}, {wall:.1f} s")
    for k in range(args.cuts):
        # a cut before the run was recorded (while the process started) leaves nothing to resume: start it again
        cmd = (station("run", "--resume", "cut", "--json", str(out / "cut.json"), *common) if recorded(out)
               else station("run", "iso9283", "--run-id", "cut", "--seed", str(seed), "--time-scale",
                            args.time_scale, "--json", str(out / "cut.json"), *common))
        child = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        delay = float(rng.uniform(0.1, 0.8)) * wall / (args.cuts - k + 0.5)
        sig = signal.SIGINT if rng.random() < 0.5 else signal.SIGKILL
        time.sleep(delay)
        hit = running_step(out / "station.sqlite", "cut")
        if child.poll() is None:
            os.kill(child.pid, sig)
        child.wait()
        print(f"cut {k + 1}: {sig.name} after {delay:.1f} s, in step {hit!r} (exit {child.returncode})"
              + ("" if recorded(out) else ": before the run was recorded"))
    if json.loads((out / "cut.json").read_text())["status"] != "done" if (out / "cut.json").exists() else True:
        fin = subprocess.run(station("run", "--resume", "cut", "--json", str(out / "cut.json"), *common), cwd=ROOT,
                             capture_output=True, text=True)
        print(f"resumed to the end: exit {fin.returncode} {fin.stdout.splitlines()[0] if fin.stdout else fin.stderr}")
    else:
        print("the last resume already finished the run")
    a, b = table(out / "ref.json"), table(out / "cut.json")
    worst = {"AP_mm": 0.0, "RP_mm": 0.0}
    for pose in sorted({p for p, _ in a if p.startswith("P") and "-" not in p}):
        n_a, n_b = a[(pose, "n_cycles")], b[(pose, "n_cycles")]
        d = {key: abs(a[(pose, key)] - b[(pose, key)]) for key in worst}
        for key in worst:
            worst[key] = max(worst[key], d[key])
        print(f"{pose}: n {n_a:.0f}/{n_b:.0f}  dAP {d['AP_mm']:.4f} mm  dRP {d['RP_mm']:.4f} mm")
    print(f"largest: dAP {worst['AP_mm']:.4f} mm, dRP {worst['RP_mm']:.4f} mm (store {out})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
