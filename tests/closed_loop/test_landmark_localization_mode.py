"""The ``landmarks`` mode in closed loop: through a GNSS outage the poles and facades the raw LiDAR sees
hold the pose (source LANDMARKS, lateral error small) and the shuttle keeps its service speed, where the
``ekf`` mode dead-reckons under Snow Lion's cap."""

import dataclasses
import math

from lastmile.core.perception_mode import PerceptionMode
from lastmile.core.vehicle_messages import PositionSource
from lastmile.runner.run_config import RunConfig
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import Scenario
from lastmile.stack.stack_settings import LocalizationMode

from .harness import RADAR, steps

OUTAGE_AT_S, OUTAGE_S = 8.0, 8.0
CAP_MPS = 0.5
# The loop alone: nothing but the lost fix could slow the shuttle down.
SCENARIO = Scenario(
    name="landmarks_outage",
    minutes=(OUTAGE_AT_S + OUTAGE_S) / 60.0,
    gnss=GnssScenario(outages=(GnssOutage(start_s=OUTAGE_AT_S, duration_s=OUTAGE_S),)),
)


def _config(base: RunConfig, mode: LocalizationMode, perception: PerceptionMode) -> RunConfig:
    return dataclasses.replace(
        base, stack=dataclasses.replace(base.stack, localization=mode, perception=perception)
    )


def _lateral_error_m(st) -> float | None:
    est = st.out.diagnostics.estimate
    if est is None:
        return None
    truth, pose = st.sim.ego_state, est.map_from_base
    return -math.sin(truth.yaw_rad) * (pose.x_m - truth.x_m) + math.cos(truth.yaw_rad) * (
        pose.y_m - truth.y_m
    )


def test_landmarks_hold_the_pose_and_the_service_speed_through_an_outage_where_the_ekf_dead_reckons():
    config = _config(RunConfig(), LocalizationMode.LANDMARKS, PerceptionMode.LIDAR_CAMERA_RADAR)
    sources: list[PositionSource] = []
    lateral: list[float] = []
    speeds: list[float] = []
    for st in steps(SCENARIO, config=config):
        if st.t_s < OUTAGE_AT_S + 1.0:  # the first second still counts the last fix
            continue
        cap = st.verdict.directive.speed_cap_mps
        assert cap is None or cap > CAP_MPS, f"capped at {st.t_s:.2f} s: {st.verdict.directive.reasons}"
        speeds.append(st.sim.ego_state.speed_mps)
        err = _lateral_error_m(st)
        if err is not None:
            lateral.append(abs(err))
            sources.append(st.out.diagnostics.estimate.source)
    assert sources and sources.count(PositionSource.LANDMARKS) >= 0.95 * len(sources), set(sources)
    assert PositionSource.DEAD_RECKONING not in sources
    assert max(lateral) < 0.10, max(lateral)
    assert min(speeds) > 4.0  # service speed, not Snow Lion's dead-reckoning creep

    # The same outage in the `ekf` mode (radar: its estimate does not depend on perception).
    ekf_sources: set[PositionSource] = set()
    capped = False
    for st in steps(SCENARIO, config=_config(RADAR, LocalizationMode.EKF, PerceptionMode.RADAR_TRACKING)):
        if st.t_s < OUTAGE_AT_S + 1.5:
            continue
        est = st.out.diagnostics.estimate
        if est is not None:
            ekf_sources.add(est.source)
        cap = st.verdict.directive.speed_cap_mps
        capped |= cap is not None and cap <= CAP_MPS
    assert ekf_sources == {PositionSource.DEAD_RECKONING} and capped
