"""Simulated servo drives, the machine's true errors and measuring instruments.

Never imports ``gateway.compensation`` or ``gateway.calibration``: the simulated truth and the
correction are written independently, so a shared mistake cannot cancel out.
"""
