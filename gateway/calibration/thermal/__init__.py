"""How a screw warms and where it grows, fitted from commissioning's readings (pure): heat
from motion fitted to the drift references or to a warm-up against a sensor, a zone
warm-up's growth shape, and the shape of the drift that commissioning's own moves leave.

thermal imports plans only (a fit replays its plan's moves); never fitting, measuring,
reporting or commissioning.
"""
