"""Errors raised by the compensation engine. Messages are one line and name the culprit."""

from __future__ import annotations


class CompensationError(ValueError):
    """A table or model that must not be used on a machine."""


class TableError(CompensationError):
    """A pitch table or planar model failed validation (names file and point)."""


class ConvergenceError(CompensationError):
    """The planar command iteration did not converge within its bounded count."""


class TravelError(CompensationError):
    """A nominal target lies outside the configured travel."""


def where(source: str, line: int | None, position: float | None, unit: str = "mm") -> str:
    """Name a table point for an error message: ``file: line 7 (position 350 mm)``."""
    text = source
    if line is not None:
        text += f": line {line}"
    if position is not None:
        text += f" (position {position:g} {unit})"
    return text


class CorrectionLimitError(CompensationError):
    """A correction larger than ``max_correction_mm`` was asked for; nothing is sent."""
