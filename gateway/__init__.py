"""compgw: a Modbus gateway that applies pitch, backlash, XY-plane and thermal compensation."""

__version__ = "0.1.0"
