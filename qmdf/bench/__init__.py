"""Benchmarks with printed figures: ``python -m qmdf.bench SUITE [--json PATH]``. Targets live here, never in
timed tests."""
