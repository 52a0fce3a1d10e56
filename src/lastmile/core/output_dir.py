"""Checking an output directory before any work starts, so a run is never lost to a bad ``--out``."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from lastmile.core.errors import ConfigError


def prepare_output_dir(path: Path, option: str = "--out") -> Path:
    """Create ``path`` (and its parents) if needed and prove it writable by writing a file in it.

    Called before a simulation starts: a run directory that cannot be written is found at once, not
    after the whole run.

    Args:
        path: the directory to write into.
        option: the option or key that named it, for the message.

    Returns:
        ``path``.

    Raises:
        ConfigError: ``path`` is an existing file, cannot be created, or cannot be written, naming what
            was expected and what arrived.
    """
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option}: expected a directory to write into, got an existing file {str(path)!r}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(
            f"{option}: expected a directory that can be created, got {str(path)!r} "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
    # os.access says yes to root on a read-only mount; writing a file is the only honest test.
    try:
        handle, probe = tempfile.mkstemp(prefix=".lastmile-write-test-", dir=path)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"{option}: expected a writable directory, got {str(path)!r} ({reason})") from None
    os.close(handle)
    os.unlink(probe)
    return path


def prepare_output_file(path: Path, option: str) -> Path:
    """Check that ``path`` can be written as a file (not a directory; its folder made and writable),
    before any work starts.

    Raises:
        ConfigError: as :func:`prepare_output_dir`, or ``path`` is a directory.
    """
    if path.is_dir():
        raise ConfigError(f"{option}: expected a file to write, got a directory {str(path)!r}")
    prepare_output_dir(path.parent, option)
    return path
