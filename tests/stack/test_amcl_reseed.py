"""The ``amcl`` mode's re-seeding rule (``stack/amcl_fusion.py``): a particle filter the EKF keeps
refusing, or that keeps recovering, restarts at the EKF's pose after ``reseed_after`` updates in a row,
but only while RTK holds that pose, never from dead reckoning (a lost filter must not be "found" again
at a drifting estimate and then confirm it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lastmile.core.geometry import SE2
from lastmile.core.stamp import Stamp
from lastmile.core.vehicle_messages import LocalizationEstimate, PositionSource
from lastmile.localization.amcl_localization import AmclSettings
from lastmile.localization.occupancy_map import write_grid
from lastmile.localization.particle_filter import AmclEstimate, OccupancyGrid
from lastmile.stack import amcl_fusion
from lastmile.stack.amcl_fusion import AmclFusion

RESEED_AFTER = 3


@dataclass
class _Filter:
    """Stands in for the particle filter: records initialisations, reports a set injection share."""

    injection: float = 0.0
    starts: list[tuple[float, float, float]] = field(default_factory=list)

    def initialise(self, pose: tuple[float, float, float], std: tuple[float, float, float]) -> None:
        self.starts.append(pose)

    def motion(self, delta: tuple[float, float, float]) -> None:
        pass

    def scan(self, ranges: np.ndarray, angles: np.ndarray) -> bool:
        return True

    def estimate(self) -> AmclEstimate:
        return AmclEstimate(
            x_m=10.0,
            y_m=0.0,
            yaw_rad=0.0,
            covariance=np.diag([0.01, 0.01, 1e-4]),
            pos_std_m=0.1,
            particles=500,
            random_injection=self.injection,
            confident=True,
        )


@dataclass
class _Ekf:
    """Stands in for the pose EKF: a pose on a straight road, its source, and a gate that refuses."""

    source: PositionSource = PositionSource.GNSS
    refuse: bool = False
    initialised: bool = True
    rejected_pose_measurements: int = 0
    x_m: float = 0.0

    def estimate(self, stamp: Stamp) -> LocalizationEstimate:
        return LocalizationEstimate(
            stamp=stamp,
            map_from_base=SE2(self.x_m, 0.0, 0.0),
            speed_mps=5.0,
            yaw_rate_radps=0.0,
            pos_std_m=0.03,
            yaw_std_rad=0.002,
            valid=True,
            source=self.source,
        )

    def update_pose(self, measurement: object, source: PositionSource) -> int:
        self.rejected_pose_measurements += self.refuse
        return int(not self.refuse)


@pytest.fixture
def fusion(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> AmclFusion:
    grid = OccupancyGrid(occupied=np.zeros((20, 20), dtype=bool), resolution_m=0.5)
    write_grid(tmp_path / "map.yaml", grid)
    out = AmclFusion(AmclSettings(map=str(tmp_path / "map.yaml"), reseed_after=RESEED_AFTER))
    out.filter = _Filter()  # type: ignore[assignment]
    monkeypatch.setattr(amcl_fusion, "planar_scan", lambda *a: (np.ones(360), np.zeros(360)))
    return out


def _clouds(fusion: AmclFusion, ekf: _Ekf, count: int, start: int = 0) -> None:
    for k in range(start, start + count):
        ekf.x_m = 0.5 * k
        cloud = SimpleNamespace(stamp=Stamp(100_000 * (k + 1)), points=np.zeros((4, 6), dtype=np.float32))
        fusion.fuse(ekf, SimpleNamespace(cloud=cloud, noise=np.zeros(4, dtype=bool)))  # type: ignore[arg-type]


@pytest.mark.parametrize("failure", ["gate", "recovering"])
def test_refused_in_a_row_while_rtk_holds_restarts_at_the_ekfs_pose(fusion: AmclFusion, failure: str) -> None:
    ekf = _Ekf(refuse=failure == "gate")
    filt: _Filter = fusion.filter  # type: ignore[assignment]
    filt.injection = 0.5 if failure == "recovering" else 0.0
    _clouds(fusion, ekf, RESEED_AFTER)
    assert len(filt.starts) == 1 and fusion.stats.reseeds == 0  # the first start only
    _clouds(fusion, ekf, 1, start=RESEED_AFTER)
    assert fusion.stats.reseeds == 1
    assert filt.starts[-1][0] == pytest.approx(0.5 * RESEED_AFTER)  # at the EKF's pose of that cloud


def test_never_reseeded_from_dead_reckoning(fusion: AmclFusion) -> None:
    ekf = _Ekf(refuse=True)
    filt: _Filter = fusion.filter  # type: ignore[assignment]
    _clouds(fusion, ekf, 1)
    ekf.source = PositionSource.DEAD_RECKONING
    _clouds(fusion, ekf, 5 * RESEED_AFTER, start=1)
    assert fusion.stats.reseeds == 0 and len(filt.starts) == 1
    ekf.source = PositionSource.GNSS  # RTK back: the next refused update restarts it
    _clouds(fusion, ekf, 1, start=5 * RESEED_AFTER + 1)
    assert fusion.stats.reseeds == 1


def test_an_accepted_update_resets_the_count(fusion: AmclFusion) -> None:
    ekf = _Ekf(refuse=True)
    _clouds(fusion, ekf, RESEED_AFTER - 1)  # refused, one short of a restart
    ekf.refuse = False
    _clouds(fusion, ekf, 1, start=RESEED_AFTER - 1)  # accepted: the count starts again
    ekf.refuse = True
    _clouds(fusion, ekf, RESEED_AFTER, start=RESEED_AFTER)
    assert fusion.stats.reseeds == 0 and fusion.stats.updates == 1
    _clouds(fusion, ekf, 1, start=2 * RESEED_AFTER)
    assert fusion.stats.reseeds == 1
