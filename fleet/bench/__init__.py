"""The benchmarks behind ``drona bench`` (see :mod:`fleet.cli.bench`), one module each."""
