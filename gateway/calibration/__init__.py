"""Calibration: plans, raw data, ISO 230-2 statistics and table fitting (pure functions).

The I/O that drives a machine through a plan lives elsewhere; everything here works on
arrays and files only, so the CLI, the demo and tests share it.
"""
