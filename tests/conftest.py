"""Test-suite settings.

Hypothesis explores new random examples on every local run; under CI (``CI`` set) it is
derandomised so a landing never depends on luck. Property tests set ``deadline=None``
themselves where a first call compiles or integrates.
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
