"""The compiled kernels live in the user's cache folder, and the install-time warm-up compiles every one
of them for the argument types real frames bring."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import lastmile
from lastmile.perception import jit_cache
from lastmile.perception.pipeline import LidarPipeline
from lastmile.perception.warmup import entry_kernels, warm_up
from tests.perception.test_ground import _level_change_scan
from tests.perception.test_pipeline import _frame


def test_kernels_are_cached_in_the_user_cache_folder_never_in_the_package() -> None:
    package = Path(lastmile.__file__).resolve().parent
    folder = jit_cache.kernel_cache_dir().resolve()
    kernels = entry_kernels()
    assert len(kernels) >= 20
    for name, fn in kernels.items():
        path = Path(fn.stats.cache_path).resolve()  # type: ignore[attr-defined]
        assert folder in path.parents, (name, path)
        assert package not in path.parents, (name, path)


def test_the_cache_folder_is_numbas_own_setting_then_lastmiles_then_the_platforms(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "n"))
    monkeypatch.setenv("LASTMILE_CACHE_DIR", str(tmp_path / "l"))
    assert jit_cache.kernel_cache_dir() == tmp_path / "n"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert jit_cache.kernel_cache_dir() == tmp_path / "l" / "numba"
    monkeypatch.delenv("LASTMILE_CACHE_DIR")
    if sys.platform.startswith("linux"):
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
        assert jit_cache.kernel_cache_dir() == tmp_path / "x" / "lastmile" / "numba"
        monkeypatch.delenv("XDG_CACHE_HOME")
        assert jit_cache.kernel_cache_dir() == Path.home() / ".cache" / "lastmile" / "numba"


def _compiled() -> dict[str, int]:
    return {name: len(fn.signatures) for name, fn in entry_kernels().items()}  # type: ignore[attr-defined]


def test_the_warm_up_compiles_every_kernel_for_the_types_real_frames_bring() -> None:
    report = warm_up()
    assert report.not_compiled == () and report.kernels == len(entry_kernels())
    before = _compiled()
    # The pipeline on other frames (the synthetic campus rig with de-skew and a curb, the same
    # without inputs, a level change that runs the fallback) needs no new compilation.
    _, sweeps, _, ext, traj = _frame()
    curb = np.array([[-20.0, -3.5], [70.0, -3.5]])
    pipe = LidarPipeline()
    pipe.process(sweeps, ext, traj, road_mask=lambda xy: np.abs(xy[:, 1]) < 3.5, map_curb_xy_m=curb)
    pipe.process(sweeps[:1], ext)
    xyz, _ = _level_change_scan(30.0)
    pipe.ground_segmenter.segment(xyz)
    assert _compiled() == before
