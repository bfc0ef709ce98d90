"""The benchmarks behind ``drona bench`` (see :mod:`fleet.cli.bench`), one module each."""

from drona_gcs.errors import DronaError


class BenchError(DronaError):
    """A benchmark could not run: the fleet under test did not come up or lost a process, a link did not
    connect, or ``--plot`` cannot be honoured."""
