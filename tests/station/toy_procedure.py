"""A deterministic procedure for runner tests, runnable as a child process.

    python -m tests.station.toy_procedure DB RUN_ID [--resume]

Each "measure k" step records 5 batches of 40 samples whose values are a
function of (k, sample index) only, so an interrupted and resumed run must
end with exactly the samples of an uninterrupted one. After each committed
batch the child prints ``ack STEP BATCH`` (flushed): what it acknowledged.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from station.runner import Procedure, Runner, Step
from station.store import RunStore

N_MEASURE = 6
BATCHES = 5
PER_BATCH = 40


def values(k: int, batch: int) -> dict[str, np.ndarray]:
    i = np.arange(batch * PER_BATCH, (batch + 1) * PER_BATCH)
    t = k * 10.0 + i * 1e-3
    return {"t": t, "x": np.sin(t) * 100 + k, "y": np.cos(3 * t), "z": i.astype(float)}


def make_procedure(delay_s: float = 0.0, announce=None) -> Procedure:
    sessions = []

    def connect(ctx):
        sessions.append(ctx.attempt)
        ctx.session["connected"] = True
        return {"sessions": len(sessions)}

    def measure(k):
        def run(ctx):
            assert ctx.session.get("connected"), "measure ran without a connected session"
            for b in range(BATCHES):
                ctx.checkpoint()
                ctx.record("tracker", values(k, b))
                if announce:
                    announce(f"ack {ctx.idx} {b}")
                if delay_s:
                    time.sleep(delay_s)
            return {"k": k}
        return run

    def compute(ctx):
        s = ctx.samples("tracker")
        return {"n": int(s["t"].size), "mean_x": float(s["x"].mean())}

    steps = [Step("connect", connect, every_session=True)]
    steps += [Step(f"measure {k}", measure(k), label=f"{k + 1}/{N_MEASURE}") for k in range(N_MEASURE)]
    steps += [Step("compute", compute)]
    return Procedure("toy", steps)


def main(argv: list[str]) -> int:
    db, run_id = argv[0], argv[1]
    store = RunStore(db)
    runner = Runner(store, make_procedure(delay_s=0.01, announce=lambda m: print(m, flush=True)))
    if "--resume" in argv:
        out = runner.resume(run_id)
    else:
        out = runner.start(run_id, params={"toy": True}, model="rb5-850", serial="SN1")
    print(f"status {out.status}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
