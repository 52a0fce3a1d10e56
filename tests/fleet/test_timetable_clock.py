"""The timetable clock hands each Table 1 run to a shuttle shortly before it departs, once a day,
and remembers across a restart which runs it has handed out (in-process: the clock is injected)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from lastmile.fleet import storage
from lastmile.fleet.auth import Principal
from lastmile.fleet.dispatcher import Dispatcher
from lastmile.fleet.scheduling import LoopRoute, Planner, due_runs
from lastmile.hdmap.service_route import campus_service


def test_due_runs_are_those_departing_within_the_lead_time_soonest_first() -> None:
    first = {"a": 8 * 3600.0, "b": 8 * 3600 + 1200.0, "c": 7 * 3600.0}
    assert due_runs(first, 8 * 3600 - 600.0, 600.0) == ["a"]
    assert due_runs(first, 8 * 3600 - 600.0, 1800.0) == ["a", "b"]
    assert due_runs(first, 8 * 3600 + 1.0, 600.0) == []  # departed: not handed out late


def test_the_clock_hands_out_each_run_once_per_day_even_across_a_restart(tmp_path: Path) -> None:
    route = LoopRoute(campus_service())
    url = storage.default_sqlite_url(tmp_path)
    seven_55 = 7 * 3600 + 55 * 60.0

    async def first_day() -> list[tuple[str, str]]:
        engine = storage.make_engine(url)
        writer = storage.Writer(engine)
        d = Dispatcher(engine, writer, route, Planner(route))
        d.load()
        writer.start(asyncio.get_running_loop())
        op = Principal("operator", "op")
        for vid in ("a", "b"):
            await d.register_vehicle(vid, "", 6)
        assert await d.auto_dispatch_timetable(seven_55, "2026-06-08", 600.0) == []  # nobody in service
        await d.command(op, "b", "start_service", "")
        handed = await d.auto_dispatch_timetable(seven_55, "2026-06-08", 600.0)
        assert [t.stop_id for t in d.trips.values() if t.run_id == "morning-0800"] == [
            "S1",
            "S2",
            "S3",
            "S4",
            "S1",
        ]
        assert await d.auto_dispatch_timetable(seven_55 + 60, "2026-06-08", 600.0) == []
        await asyncio.get_running_loop().run_in_executor(None, writer.stop)
        engine.dispose()
        return handed

    async def after_restart() -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
        engine = storage.make_engine(url)
        writer = storage.Writer(engine)
        d = Dispatcher(engine, writer, route, Planner(route))
        d.load()
        writer.start(asyncio.get_running_loop())
        # The run's trips are done (the shuttle served it); the clock still must not hand it out again.
        for t in [t for t in d.trips.values() if t.run_id == "morning-0800"]:
            assert await d.trip_done("b", t.id)
        same_day = await d.auto_dispatch_timetable(seven_55, "2026-06-08", 600.0)
        next_day = await d.auto_dispatch_timetable(seven_55, "2026-06-09", 600.0)
        await asyncio.get_running_loop().run_in_executor(None, writer.stop)
        engine.dispose()
        return same_day, next_day

    assert asyncio.run(first_day()) == [("morning-0800", "b")]
    same_day, next_day = asyncio.run(after_restart())
    assert same_day == [] and next_day == [("morning-0800", "b")]
