"""The user's cache folder (compiled kernels live there, never inside the installed package)."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def user_cache_dir(app: str = "lastmile") -> Path:
    """``$XDG_CACHE_HOME/<app>`` (``~/.cache/<app>``) on Linux, ``~/Library/Caches/<app>`` on macOS,
    ``%LOCALAPPDATA%\\<app>\\Cache`` on Windows, as each platform's conventions say."""
    if sys.platform == "win32":
        base = os.environ.get("LOCALAPPDATA") or str(Path.home() / "AppData" / "Local")
        return Path(base) / app / "Cache"
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / app
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / app


def use_user_cache_for_numba() -> Path:
    """Point Numba's on-disk cache at the user's cache folder unless ``NUMBA_CACHE_DIR`` is set.

    Numba caches beside the source by default: inside site-packages, which a user may not be able to
    write (then every run compiles again) and which a package manager owns. Returns the folder used.
    """
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen:
        return Path(chosen)
    path = user_cache_dir() / "numba"
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    numba = sys.modules.get("numba")
    if numba is not None:  # imported before us: its config already read the environment
        numba.config.CACHE_DIR = str(path)
    return path
