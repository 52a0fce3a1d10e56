"""The run log records what held the pose and the GNSS fix over time; the report shows it."""

import dataclasses
import itertools

from lastmile.evaluation.localization_timeline import (
    localization_lines,
    localization_mode,
    localization_spans,
)
from lastmile.runner.closed_loop import run_scenario
from lastmile.sim.gnss_scenario import GnssOutage, GnssScenario
from lastmile.sim.scenario import default_service

from .harness import RADAR


def test_an_outage_shows_in_the_run_log_as_no_fix_then_dead_reckoning_then_rtk_again():
    scenario = dataclasses.replace(
        default_service(seed=0, minutes=0.2),
        gnss=GnssScenario(outages=(GnssOutage(start_s=4.0, duration_s=4.0),)),
    )
    log = run_scenario(scenario, RADAR)
    spans = localization_spans(log, 12.0)
    seq = [(sp.source, sp.gnss) for sp in spans]
    assert seq[:2] == [("invalid", "none_yet"), ("gnss", "rtk_fixed")]  # no pose before the first fix
    assert ("gnss", "no_fix") in seq  # the fix is gone; the last one still holds the pose for 1 s
    dr = [sp for sp in spans if sp.source == "dead_reckoning"]
    assert dr and 4.9 < dr[0].start_s < 5.3  # 1 s after the last accepted fix
    assert seq[-1] == ("gnss", "rtk_fixed") and 8.0 <= spans[-1].start_s < 8.5
    assert dr[0].pos_std_m > spans[1].pos_std_m  # the sigma has grown on dead reckoning
    assert spans[-1].end_s == 12.0 and all(a.end_s == b.start_s for a, b in itertools.pairwise(spans))
    text = "\n".join(localization_lines(log, 12.0))
    assert localization_mode(log) == "ekf" and "Localization mode: **ekf**" in text
    assert "| dead_reckoning | no_fix |" in text
