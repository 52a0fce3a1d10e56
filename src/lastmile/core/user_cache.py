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
    xdg = os.environ.get("XDG_CACHE_HOME")
    # The XDG spec says a relative path is invalid and to be ignored.
    return (Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache") / app


def kernel_cache_dir() -> Path:
    """Where compiled (Numba) kernels are cached: ``NUMBA_CACHE_DIR`` when the user sets it (Numba's
    own setting, respected as is), else ``LASTMILE_CACHE_DIR``/numba, else the platform's user cache
    folder's ``numba`` (:func:`user_cache_dir`)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    own = os.environ.get("LASTMILE_CACHE_DIR")
    return (Path(own) if own else user_cache_dir()) / "numba"
