"""Exceptions for bad input: each names what was expected and what arrived."""

from __future__ import annotations


class LastmileError(Exception):
    """Base of every error a user can cause and fix (bad file, bad option, bad message)."""


class ConfigError(LastmileError):
    """A configuration or scenario value is unknown, missing or out of range."""


class MapError(LastmileError):
    """A map file is missing, malformed, or lacks what the stack needs."""


class MessageError(LastmileError):
    """A message failed validation (wrong shape, NaN, out-of-range value)."""


class RoutingError(LastmileError):
    """No route exists between the requested places."""


def expect(condition: bool, error: type[LastmileError], what: str, expected: str, got: object) -> None:
    """Raise ``error`` with a message naming what was expected and what arrived, unless ``condition``."""
    if not condition:
        raise error(f"{what}: expected {expected}, got {got!r}")


class CalibrationError(LastmileError):
    """A sensor calibration cannot be trusted: too little overlap, too few planes, no convergence."""
