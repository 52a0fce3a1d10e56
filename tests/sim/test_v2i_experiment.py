import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.sim.infrastructure import CrossingCamera, CrossingCameraConfig
from lastmile.sim.v2i_experiment import V2iConfig, run_policy, run_v2i_experiment


@pytest.fixture(scope="module")
def result():
    return run_v2i_experiment(V2iConfig(), speeds_mps=(1.0, 2.0), vehicle_counts=(1, 3), laps=6, seeds=(0, 1))


def test_the_time_gained_grows_with_laps(result):
    for gain in result.cumulative_gain_s.values():
        assert gain[-1] > gain[2] > 0.0


def test_the_gain_is_larger_at_the_higher_speed(result):
    assert result.cumulative_gain_s[(2.0, 1)][-1] > result.cumulative_gain_s[(1.0, 1)][-1]


def test_each_vehicle_gains_more_in_a_larger_fleet(result):
    for speed in (1.0, 2.0):
        assert result.cumulative_gain_s[(speed, 3)][-1] > result.cumulative_gain_s[(speed, 1)][-1]


def test_the_baseline_stops_and_looks_every_lap():
    c = V2iConfig(pedestrian_rate_per_s=0.0)  # nobody ever crosses: only the stop-and-look costs time
    base = np.array(run_policy(c, "baseline", 1, 2.0, 4, seed=0)[0])
    infra = np.array(run_policy(c, "infrastructure", 1, 2.0, 4, seed=0)[0])
    free_lap_s = c.loop_m / 2.0
    assert np.allclose(infra[1:], free_lap_s, atol=0.1)  # never slows when told the crossing is clear
    # Braking to a stop and pulling away at 2 m/s costs about v/2 (1/a + 1/b) s, plus the look.
    assert np.all(base[1:] > free_lap_s + c.look_s + 0.9)


def test_the_camera_delivers_its_latest_broadcast_after_the_latency():
    camera = CrossingCamera(
        CrossingCameraConfig(rate_hz=1.0, latency_s=0.3, miss_probability=0.0), np.random.default_rng(0)
    )
    seen = []
    for k in range(40):
        t = k * 0.05
        camera.step(t, truly_present=t >= 0.5)
        seen.append(None if camera.latest is None else camera.latest.pedestrians_present)
    assert seen[5] is None  # nothing received before 0.3 s
    assert seen[7] is False  # the 0 s broadcast (nobody yet)
    assert seen[25] is False  # at 1 Hz the 0.5 s arrival waits for the 1.0 s broadcast...
    assert seen[27] is True  # ...received at 1.3 s


def test_bad_experiment_settings_name_what_was_expected():
    with pytest.raises(ConfigError, match="vehicles"):
        run_policy(V2iConfig(), "baseline", 0, 1.0, 1, seed=0)
    with pytest.raises(ConfigError, match="policy"):
        run_policy(V2iConfig(), "teleport", 1, 1.0, 1, seed=0)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="rate_hz"):
        CrossingCameraConfig(rate_hz=0.0)
