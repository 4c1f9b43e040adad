"""Hypothesis profiles of the suite. 'ci' (the default): derandomized, no example database, so a
run draws the same examples every time, a failure is reproduced by rerunning it, and nothing is
written into the checkout. 'random': fresh examples every run (still no database), for a longer
search on demand: ``NRMICP_HYPOTHESIS=random python -m pytest tests/test_bad_input.py``."""
import os

from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("random", derandomize=False, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow], print_blob=True)
settings.load_profile(os.environ.get("NRMICP_HYPOTHESIS", "ci"))
