"""Benchmark workloads (pure and seeded; the timing loop lives at the edge, in ``fleet.cli.bench``)."""
