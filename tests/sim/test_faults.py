import math

import numpy as np
import pytest

from lastmile.core.errors import ConfigError
from lastmile.core.sensor_frames import GnssInsFrame, ImuFrame, RadarFrame, StopCallFrame
from lastmile.core.stamp import Stamp
from lastmile.sim.faults import FaultInjector, FaultSpec
from lastmile.sim.scenario import Scenario, load_scenario


def _gnss(t_s: float) -> GnssInsFrame:
    return GnssInsFrame(
        stamp=Stamp(round(t_s * 1e6)),
        x_m=10.0,
        y_m=20.0,
        yaw_rad=0.1,
        speed_mps=3.0,
        pos_std_m=0.05,
        yaw_std_rad=0.01,
    )


def _radar(t_s: float, x_m: float = 12.0) -> RadarFrame:
    return RadarFrame(
        stamp=Stamp(round(t_s * 1e6)), sensor_id="front", objects=np.array([[x_m, 0.5, 1.0, 0.0, 5.0, -2.0]])
    )


def _inject(fault: FaultSpec, frame, t_s: float, latency_us: int = 20_000):
    return FaultInjector((fault,), seed=3).capture(frame, latency_us, t_s)


def test_faults_act_only_inside_their_window():
    f = FaultSpec(kind="dropout", target="radar_front", start_s=10.0, duration_s=5.0)
    inj = FaultInjector((f,), seed=0)
    assert inj.capture(_radar(9.99), 20_000, 9.99) != []
    assert inj.capture(_radar(10.0), 20_000, 10.0) == []
    assert inj.capture(_radar(14.99), 20_000, 14.99) == []
    assert inj.capture(_radar(15.0), 20_000, 15.0) != []


def test_a_fault_on_one_sensor_leaves_the_others_alone():
    f = FaultSpec(kind="dropout", target="radar_rear", start_s=0.0, duration_s=100.0)
    radar = _radar(1.0)
    assert _inject(f, radar, 1.0) == [(radar, 20_000)]  # the same object, untouched
    assert _inject(f, _gnss(1.0), 1.0) == [(_gnss(1.0), 20_000)]


def test_frozen_sensor_repeats_its_last_payload_under_fresh_stamps():
    f = FaultSpec(kind="frozen", target="radar_front", start_s=1.0, duration_s=5.0)
    inj = FaultInjector((f,), seed=0)
    first = inj.capture(_radar(1.0, x_m=12.0), 20_000, 1.0)[0][0]
    later = inj.capture(_radar(2.0, x_m=30.0), 20_000, 2.0)[0][0]
    assert later.stamp == Stamp(2_000_000)
    assert np.array_equal(later.objects, first.objects)


def test_latency_spike_and_out_of_order_delay_delivery():
    spike = FaultSpec(kind="latency_spike", target="gnss", start_s=0.0, duration_s=9.0, latency_ms=400.0)
    assert _inject(spike, _gnss(1.0), 1.0)[0][1] == 20_000 + 400_000
    jitter = FaultSpec(kind="out_of_order", target="gnss", start_s=0.0, duration_s=9.0, jitter_ms=300.0)
    inj = FaultInjector((jitter,), seed=5)
    latencies = [inj.capture(_gnss(1.0), 20_000, 1.0)[0][1] for _ in range(50)]
    assert min(latencies) >= 20_000 and max(latencies) <= 320_000
    assert len(set(latencies)) > 40  # random per frame, so consecutive frames swap places


def test_nan_garbage_and_blind_corrupt_what_the_sensor_sends():
    nan = _inject(FaultSpec(kind="nan", target="gnss", start_s=0, duration_s=9), _gnss(1.0), 1.0)[0][0]
    assert math.isnan(nan.x_m)
    garbage = _inject(
        FaultSpec(kind="garbage", target="radar_front", start_s=0, duration_s=9), _radar(1.0), 1.0
    )
    assert len(garbage[0][0].objects) >= 20 and np.abs(garbage[0][0].objects).max() > 50.0
    blind = _inject(FaultSpec(kind="blind", target="radar_front", start_s=0, duration_s=9), _radar(1.0), 1.0)
    assert len(blind[0][0].objects) == 0
    imu = ImuFrame(stamp=Stamp(1_000_000), yaw_rate_radps=0.1, accel_x_mps2=0.0, accel_y_mps2=0.0)
    assert math.isnan(
        _inject(FaultSpec(kind="nan", target="imu", start_s=0, duration_s=9), imu, 1.0)[0][0].yaw_rate_radps
    )


def test_gnss_outage_drifts_and_says_so_while_multipath_lies_about_its_accuracy():
    outage = FaultSpec(kind="gnss_outage", target="gnss", start_s=0.0, duration_s=60.0)
    out = _inject(outage, _gnss(20.0), 20.0)[0][0]
    assert not out.fix_ok and out.x_m == pytest.approx(20.0) and out.pos_std_m > 5.0
    mp = FaultSpec(kind="gnss_multipath", target="gnss", start_s=0.0, duration_s=60.0, offset_m=6.0)
    out = _inject(mp, _gnss(20.0), 20.0)[0][0]
    assert out.fix_ok and out.pos_std_m == 0.05
    assert math.hypot(out.x_m - 10.0, out.y_m - 20.0) == pytest.approx(6.0)


def test_map_misalignment_offsets_every_fix_by_the_same_amount():
    f = FaultSpec(kind="map_misalignment", target="map", start_s=0.0, duration_s=60.0, offset_m=1.5)
    inj = FaultInjector((f,), seed=0)
    xs = [inj.capture(_gnss(t), 20_000, t)[0][0].x_m for t in (1.0, 2.0, 3.0)]
    assert xs == [11.5, 11.5, 11.5]


def test_v2i_calls_are_never_faulted():
    f = FaultSpec(kind="dropout", target="gnss", start_s=0.0, duration_s=60.0)
    call = StopCallFrame(stamp=Stamp(1_000_000), stop_id="S1", source="stop_button")
    assert _inject(f, call, 1.0) == [(call, 20_000)]


def test_module_faults_are_reported_to_the_runner():
    inj = FaultInjector(
        (FaultSpec(kind="module_hang", target="planning", start_s=5.0, duration_s=2.0),), seed=0
    )
    assert inj.module_fault("planning", 4.0) is None
    assert inj.module_fault("planning", 6.0) == "hang"
    assert inj.module_fault("control", 6.0) is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"kind": "melt", "target": "gnss"}, "fault.kind"),
        ({"kind": "dropout", "target": "sonar"}, "fault.target"),
        ({"kind": "nan", "target": "radar_front"}, "fault.target"),
        ({"kind": "module_raise", "target": "gnss"}, "fault.target"),
        ({"kind": "dropout", "target": "gnss", "duration_s": -1.0}, "fault.duration_s"),
    ],
)
def test_a_bad_fault_names_what_was_expected(kwargs, message):
    spec = {"start_s": 0.0, "duration_s": 1.0, **kwargs}
    with pytest.raises(ConfigError, match=message):
        FaultSpec(**spec)


def test_faults_load_from_a_scenario_file(tmp_path):
    path = tmp_path / "faulty.toml"
    path.write_text(
        'name = "faulty"\nminutes = 1.0\n\n[[faults]]\nkind = "gnss_outage"\ntarget = "gnss"\n'
        "start_s = 20.0\nduration_s = 15.0\n"
    )
    scenario = load_scenario(path)
    assert isinstance(scenario, Scenario)
    assert scenario.faults == (FaultSpec(kind="gnss_outage", target="gnss", start_s=20.0, duration_s=15.0),)
