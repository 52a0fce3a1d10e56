"""The ``scan_matching`` mode in closed loop, on a map the stack built itself.

A mapping drive (seed 1: other traffic, other sensor noise) records the LiDAR sweeps and the stack's own
poses (:class:`lastmile.runner.map_recording.LidarMapRecording`); ``map build`` turns the recording into
a PCD map. The service then drives (seed 0) through a GNSS outage in the ``scan_matching`` mode: every
LiDAR frame registered to that map holds the pose (source SCAN_MATCHING, never dead reckoning, lateral
error small) and the shuttle keeps its service speed, where the ``ekf`` mode dead-reckons under Snow
Lion's cap (``test_landmark_localization_mode.py`` shows that side on the same road).
"""

import dataclasses
import math
from pathlib import Path

import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.vehicle_messages import PositionSource
from lastmile.localization.map_build import MapBuildConfig
from lastmile.localization.scan_match_localization import ScanMatchingSettings
from lastmile.runner.closed_loop import build_closed_loop
from lastmile.runner.map_build_replay import build_map
from lastmile.runner.map_recording import LidarMapRecording
from lastmile.runner.run_config import RunConfig
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import Scenario
from lastmile.stack.stack_settings import LocalizationMode, StackSettings

from .harness import steps

OUTAGE_AT_S, OUTAGE_S = 5.0, 5.0
MAPPING_S = 12.0  # the mapping drive reaches farther than the service run below (its LiDARs see 60 m ahead)
CAP_MPS = 0.5


@pytest.fixture(scope="module")
def campus_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("mapping")
    recording = LidarMapRecording(folder / "drive.mcap", min_travel_m=2.0)
    drive = Scenario(name="mapping_drive", minutes=MAPPING_S / 60.0, seed=1)
    loop = build_closed_loop(drive, RunConfig(), (recording,))
    loop.run(round(MAPPING_S * 1e6 / loop.tick_us))
    out = folder / "campus.pcd"
    result = build_map(folder / "drive.mcap", out, MapBuildConfig())
    assert result.info.frames_used > 10 and result.info.frames_registered >= 0.5 * result.info.frames_used
    return out


def _lateral_error_m(st) -> float | None:
    est = st.out.diagnostics.estimate
    if est is None:
        return None
    truth, pose = st.sim.ego_state, est.map_from_base
    return -math.sin(truth.yaw_rad) * (pose.x_m - truth.x_m) + math.cos(truth.yaw_rad) * (
        pose.y_m - truth.y_m
    )


def test_scans_on_the_built_map_hold_the_pose_and_the_speed_through_an_outage(campus_map: Path) -> None:
    scenario = Scenario(
        name="scan_matching_outage",
        minutes=(OUTAGE_AT_S + OUTAGE_S) / 60.0,
        gnss=GnssScenario(outages=(GnssOutage(start_s=OUTAGE_AT_S, duration_s=OUTAGE_S),)),
    )
    base = RunConfig()
    config = dataclasses.replace(
        base,
        stack=dataclasses.replace(
            base.stack,
            localization=LocalizationMode.SCAN_MATCHING,
            scan_matching=ScanMatchingSettings(map=str(campus_map)),
        ),
    )
    sources: list[PositionSource] = []
    lateral: list[float] = []
    speeds: list[float] = []
    for st in steps(scenario, config=config):
        if st.t_s < OUTAGE_AT_S + 1.0:  # the first second still counts the last fix
            continue
        cap = st.verdict.directive.speed_cap_mps
        assert cap is None or cap > CAP_MPS, f"capped at {st.t_s:.2f} s: {st.verdict.directive.reasons}"
        speeds.append(st.sim.ego_state.speed_mps)
        err = _lateral_error_m(st)
        if err is not None:
            lateral.append(abs(err))
            sources.append(st.out.diagnostics.estimate.source)
    assert sources and sources.count(PositionSource.SCAN_MATCHING) >= 0.95 * len(sources), set(sources)
    assert PositionSource.DEAD_RECKONING not in sources
    assert max(lateral) < 0.10, max(lateral)
    assert min(speeds) > 4.0  # service speed, not Snow Lion's dead-reckoning creep


def test_refused_at_configuration_time_with_radar_or_without_a_good_map(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="expected raw LiDAR perception"):
        StackSettings(localization=LocalizationMode.SCAN_MATCHING, perception=PerceptionMode.RADAR_TRACKING)
    with pytest.raises(
        ConfigError, match=r"stack.scan_matching.map: expected the point-cloud map .* got none"
    ):
        StackSettings(localization=LocalizationMode.SCAN_MATCHING)
    with pytest.raises(ConfigError, match="no such file"):
        StackSettings(
            localization=LocalizationMode.SCAN_MATCHING,
            scan_matching=ScanMatchingSettings(map=str(tmp_path / "none.pcd")),
        )
    bad = tmp_path / "bad.pcd"
    bad.write_text("VERSION 0.7\nFIELDS x y\n")
    with pytest.raises(ConfigError, match="expected a PCD point cloud") as info:
        StackSettings(
            localization=LocalizationMode.SCAN_MATCHING, scan_matching=ScanMatchingSettings(map=str(bad))
        )
    assert "\n" not in str(info.value)
