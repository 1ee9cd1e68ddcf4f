"""Hypothesis budgets: ``fuzz`` (the suite's, a few seconds) and ``long`` (bench/bench_fuzz.py).

Both draw new examples every run, also under ``CI=true`` (where hypothesis would otherwise fall
back to its derandomised ``ci`` profile and draw the same examples every time): the examples come
from the session seed of tests/seeding.py, so ``--seed N`` replays a run's examples. No example
database: what a run draws depends on the seed alone.
"""

from hypothesis import HealthCheck, settings

settings.register_profile("fuzz", max_examples=150, deadline=None, derandomize=False, database=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("long", max_examples=5000, deadline=None, derandomize=False, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.load_profile("fuzz")
