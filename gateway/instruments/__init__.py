"""Measuring instruments, whatever their kind, read through one small interface.

:mod:`.base` holds what every kind shares (channel order, units, the wait for a stable
reading, retries, one-line errors); a kind fills a few hooks: :mod:`.modbus` (compgw's own
register layout, the simulator's), :mod:`.bridge` (the line protocol of
``docs/instruments-bridge.md``, over TCP or a child process), :mod:`.manual` (a gauge read
by eye at the terminal). Recordings and capture exports are read after the moves:
:mod:`.recording` finds the stops in a laser's continuous recording and aligns them with
the plan, :mod:`.capture` maps an exported table of readings. :mod:`.spec` parses the one
option syntax (``KIND:ARGS``) they are chosen by.

This package imports nothing of calibration: calibration imports it.
"""
