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
