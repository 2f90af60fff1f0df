"""What to measure and what a measurement leaves: the plans (ISO 230-2 linear and
verification, backlash, the XY grid) and the plan CSV; the raw-data CSV, its
durable writer and the readings arranged per target; the runner that turns a plan into a raw
file, handed a move and a measure coroutine so it knows no transport.

The ground floor of calibration: plans imports nothing else of it.
"""
