"""GEM's waypoint follower: sequential targets within 2 m, the sqrt(0.5 r) speed cap, the file reader."""

import math

import numpy as np
import pytest

from lastmile.control.waypoint_follower import (
    GemWaypointFollower,
    WaypointFollowerConfig,
    curvature_capped_speeds_mps,
    read_waypoint_file,
)
from lastmile.core.errors import ConfigError, MessageError
from lastmile.core.geometry import SE2
from lastmile.core.polyline import Polyline
from lastmile.core.vehicle import VehicleGeometry

STRAIGHT = Polyline(np.array([[0.0, 0.0], [100.0, 0.0]]))


def test_target_is_the_first_waypoint_at_least_2_m_away_and_never_behind():
    f = GemWaypointFollower(VehicleGeometry(all_wheel_steer=False))
    f.step(0.02, SE2(10.2, 0.0, 0.0), 3.0, STRAIGHT)
    assert f._target_s_m == pytest.approx(13.0)  # 11 and 12 are within 2 m
    f.step(0.02, SE2(10.9, 0.0, 0.0), 3.0, STRAIGHT)
    assert f._target_s_m == pytest.approx(13.0)  # still 2.1 m away: kept
    f.step(0.02, SE2(11.5, 0.0, 0.0), 3.0, STRAIGHT)
    assert f._target_s_m == pytest.approx(14.0)
    # A jump past the target (a missed waypoint) never makes the follower turn back for it.
    f.step(0.02, SE2(30.0, 0.5, 0.0), 3.0, STRAIGHT)
    assert f._target_s_m >= 30.0


def test_target_carries_over_to_a_new_path():
    f = GemWaypointFollower(VehicleGeometry(all_wheel_steer=False))
    f.step(0.02, SE2(10.2, 0.0, 0.0), 3.0, STRAIGHT)
    shifted = Polyline(np.array([[5.0, 0.0], [100.0, 0.0]]))
    f.step(0.02, SE2(10.3, 0.0, 0.0), 3.0, shifted)
    assert f._target_s_m == pytest.approx(8.0)  # x = 13 on the new path's stations


def test_yaw_rate_law_through_the_bicycle_model():
    g = VehicleGeometry(all_wheel_steer=False, max_steer_rate_radps=1e6)
    f = GemWaypointFollower(g)
    # Target 2.x m ahead, 0.2 rad left of the heading.
    delta, rear = f.step(0.02, SE2(0.0, 0.0, -0.2), 3.0, STRAIGHT)
    x, y = 3.0, 0.0  # first waypoint beyond 2 m from the rear axle at the origin
    theta = math.atan2(y, x) + 0.2
    assert delta == pytest.approx(math.atan(3.0 * theta * g.wheelbase_m / 3.0), abs=1e-6)
    assert rear == 0.0


def test_recorded_speeds_capped_by_sqrt_half_radius():
    t = np.linspace(0.0, np.pi, 40)
    r = 8.0
    xy = np.c_[r * np.cos(t), r * np.sin(t)]
    v = curvature_capped_speeds_mps(xy, np.full(40, 5.0))
    assert np.allclose(v[3:-3], math.sqrt(0.5 * r), rtol=0.02)
    straight = curvature_capped_speeds_mps(np.c_[np.arange(10.0), np.zeros(10)], np.full(10, 5.0))
    assert np.all(straight == 5.0)


def test_waypoint_file_read_projected_and_capped(tmp_path):
    p = tmp_path / "loop.csv"
    lines = ["# lat, lon, speed"]
    for k in range(30):
        lines.append(f"{43.0 + k * 1e-5:.6f}, {-80.0:.6f}, 3.0")
    p.write_text("\n".join(lines) + "\n\n")
    wf = read_waypoint_file(p, lambda lat, lon: ((lon + 80.0) * 1e5, (lat - 43.0) * 1e5))
    assert wf.xy_m.shape == (30, 2)
    assert wf.xy_m[-1, 1] == pytest.approx(29.0)
    assert np.all(wf.speed_mps == 3.0)
    assert wf.path().length_m == pytest.approx(29.0)
    assert wf.speed_at_mps(10.5) == 3.0


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("43.0, -80.0", "line 2.*latitude, longitude, speed"),
        ("43.0, x, 3", "three numbers"),
        ("95.0, -80.0, 3", "latitude in"),
        ("43.0, -80.0, -1", "line 2, column speed"),
    ],
)
def test_bad_waypoint_lines_are_named(tmp_path, line, message):
    p = tmp_path / "bad.csv"
    p.write_text(f"43.0, -80.0, 3.0\n{line}\n43.0, -80.0, 3.0\n")
    with pytest.raises(MessageError, match=message):
        read_waypoint_file(p, lambda lat, lon: (lat, lon))


def test_config_checked():
    with pytest.raises(ConfigError, match="switch_radius_m"):
        WaypointFollowerConfig(spacing_m=3.0, switch_radius_m=2.0)


def test_gain_scales_down_below_the_reference_speed_and_gems_law_is_kept_on_request():
    g = VehicleGeometry(all_wheel_steer=False, max_steer_rate_radps=1e6)
    scaled = GemWaypointFollower(g)
    published = GemWaypointFollower(g, WaypointFollowerConfig(gain_reference_speed_mps=None))
    pose = SE2(0.0, 0.0, -0.05)
    d_scaled, _ = scaled.step(0.02, pose, 1.0, STRAIGHT)
    d_pub, _ = published.step(0.02, pose, 1.0, STRAIGHT)
    theta = 0.05
    assert d_pub == pytest.approx(math.atan(3.0 * theta * g.wheelbase_m / 1.0), abs=1e-6)
    # Scaled: the wheel angle GEM's law gives at 3 m/s for the same bearing error.
    assert d_scaled == pytest.approx(math.atan(3.0 * theta * g.wheelbase_m / 3.0), abs=1e-6)


def test_live_path_speed_cap_is_gems_sqrt_half_radius_reached_by_braking():
    """Straight for 20 m, then an arc of radius 8 m: on the arc the cap is sqrt(0.5 r) = 2 m/s; before
    it, whatever braking at 0.8 m/s^2 still reaches that (the other controllers leave the cap alone)."""
    t = np.linspace(0.0, np.pi / 2, 60)
    arc = np.c_[20.0 + 8.0 * np.sin(t), 8.0 - 8.0 * np.cos(t)]
    path = Polyline(np.r_[np.c_[np.arange(0.0, 20.0, 1.0), np.zeros(20)], arc[1:]])
    gem = GemWaypointFollower(VehicleGeometry())
    on_arc = gem.speed_cap_mps(path, 24.0, 5.5, 0.8)
    assert on_arc == pytest.approx(2.0, rel=0.03)
    before = gem.speed_cap_mps(path, 10.0, 5.5, 0.8)
    assert before == pytest.approx(math.sqrt(2.0**2 + 2 * 0.8 * 10.0), rel=0.05)
    assert gem.speed_cap_mps(STRAIGHT, 10.0, 5.5, 0.8) == 5.5
