"""Hypothesis budgets: ``fuzz`` (the suite's, a few seconds) and ``long`` (bench/bench_fuzz.py)."""

from hypothesis import HealthCheck, settings

settings.register_profile("fuzz", max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("long", max_examples=5000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.load_profile("fuzz")
