"""Benchmarks for lpam against vcstool and plain git (`python -m bench.run`).

Not part of the test suite and free of timing assertions: these machines are noisy, so the
figures are medians and minima of repeated runs, read as ratios between tools measured side
by side in one run. See docs/benchmarks.md.
"""
