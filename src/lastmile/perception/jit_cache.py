"""Where the compiled perception kernels are cached: the user's cache folder, never the installed package.

Numba's own default writes the cache into ``__pycache__`` beside the kernel modules whenever that
folder is writable: inside a virtual environment's ``site-packages``, where a read-only or shared
install, a wheel's RECORD and an uninstall do not expect files to appear. Every kernel module imports
:data:`njit` from here, so the folder is chosen before the first kernel is decorated (Numba picks a
function's cache locator at decoration).

The folder, in order:

1. ``NUMBA_CACHE_DIR`` when the user sets it (Numba's own setting, respected as is);
2. ``LASTMILE_CACHE_DIR``/numba;
3. the platform's user cache folder: ``$XDG_CACHE_HOME`` or ``~/.cache`` on Linux,
   ``~/Library/Caches`` on macOS, ``%LOCALAPPDATA%`` on Windows, then ``lastmile/numba``.

Numba keys each module's entries by the module's full path inside the folder, so two installs (two
virtual environments, a checkout and a wheel) never share or overwrite each other's kernels, and an
entry is recompiled when its source file changes. ``lastmile warmup`` (or
``python -m lastmile.perception.warmup``, which ``scripts/bootstrap.sh`` runs once per install)
fills the folder ahead of the first run.
"""

from __future__ import annotations

import os

import numba
from numba import njit

from lastmile.core.user_cache import kernel_cache_dir

__all__ = ["kernel_cache_dir", "njit"]


# Set on Numba's config module, not in the environment: child processes and other libraries keep
# their own setting, and Numba's config reload leaves a value set here alone while the NUMBA_*
# environment is unchanged.
if not os.environ.get("NUMBA_CACHE_DIR"):
    numba.config.CACHE_DIR = str(kernel_cache_dir())
