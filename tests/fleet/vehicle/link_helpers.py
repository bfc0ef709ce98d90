"""Shared helpers of the vehicle link contract tests (``test_link*.py``): the backends,
personalities and transports every contract test runs over, and what each cannot do.
"""

from __future__ import annotations

import pytest

from tests.fakes.autopilot import BACKENDS

backends = pytest.mark.parametrize("backend", sorted(BACKENDS))
personalities = pytest.mark.parametrize("personality", ["ardupilot", "px4"])
transports = pytest.mark.parametrize("transport", ["udp", "tcp", "serial"])
