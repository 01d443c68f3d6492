"""Test-wide settings.

Under CI (the environment variable ``CI`` is set) hypothesis runs derandomized: every run of
the suite draws the same examples, so a landing never depends on the luck of the draw. Locally
the draws are random (and failures are replayed from ``.hypothesis/``), which is where new
counterexamples are found; each one found is kept as an explicit test.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
