"""Long fuzz run: every property of tests/fuzz (the wire decoders, configs, URLs, PLY, programs, and every file
reader over whole files and absurd numbers: tests/fuzz/test_fuzz_files.py) with 5,000 examples each (hypothesis
profile ``long``).

Run by hand: ``.venv/bin/python bench/bench_fuzz.py [--profile long]``. Prints hypothesis's
statistics per target (examples, time, share of invalid draws) and the wall time; a foreign
exception fails the run with its shrunk reproducer.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="long")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(ROOT / "tests" / "fuzz"),
                          f"--hypothesis-profile={args.profile}", "--hypothesis-show-statistics",
                          "--timeout=0"],  # 5,000 examples of a file reader take minutes: no per-test limit
                         cwd=ROOT)
    print(f"wall time {time.perf_counter() - t0:.1f} s, exit {rc}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
