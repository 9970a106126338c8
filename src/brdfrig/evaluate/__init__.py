"""Benchmarks shipped with the tool (``brdfrig bench``): time against error, ground-truth cache, plots."""
