"""Compiled kernels cache in the user's cache folder, never inside the installed package."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lastmile.core import user_cache

SRC = Path(__file__).resolve().parents[2] / "src"


def test_the_cache_folder_follows_xdg_on_linux(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    if sys.platform in ("win32", "darwin"):
        pytest.skip("XDG_CACHE_HOME is the Linux convention")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert user_cache.user_cache_dir() == tmp_path / "lastmile"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert user_cache.user_cache_dir() == Path.home() / ".cache" / "lastmile"


def test_numba_compiles_into_the_user_cache_not_the_package(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(tmp_path), PYTHONPATH=str(SRC))
    code = (
        "import numpy as np, numba\n"
        "from lastmile.perception import deskew_kernel\n"
        "deskew_kernel.time_bins(0, np.zeros(3, dtype=np.int64), 1000)\n"
        "print(numba.config.CACHE_DIR)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == str(tmp_path / "lastmile" / "numba")
    assert any((tmp_path / "lastmile" / "numba").rglob("*.nbi"))  # the kernels' cache index landed there


def test_a_users_own_numba_cache_dir_is_kept(tmp_path: Path) -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "mine"), "PYTHONPATH": str(SRC)}
    code = "import lastmile.perception, numba; print(numba.config.CACHE_DIR)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.stdout.strip() == str(tmp_path / "mine")
