"""Driving a machine through a running gateway and reading its instruments (machine), and a
calibration session on it: a plan run with compensation off or on, the seed-001 iteration
of measure, fit, write and reload, the identification config (session).

measuring imports plans and fitting (and the command line's FROM_CONFIG from
``..cli_common``); never reporting or commissioning.
"""
