import math

import numpy as np

from lastmile.core.object_class import ObjectClass
from lastmile.core.objects import TRACK_COLUMNS, TrackedObjects
from lastmile.decision.right_of_way import ArrivalOrder, EntryLine

BOX = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
# Side entry from the south: traffic heads north (+y) and stops at y = -1.
SIDE = EntryLine(stop_line_id=3, mid_x_m=7.0, mid_y_m=-1.0, heading_rad=math.pi / 2)


def _tracks(rows: dict[int, tuple[float, float, float, float]]) -> TrackedObjects:
    table = []
    for x, y, vx, vy in rows.values():
        row = [0.0] * len(TRACK_COLUMNS)
        row[0:4] = [x, y, vx, vy]
        row[4:6] = [4.5, 1.8]
        row[7] = float(ObjectClass.CAR)
        table.append(row)
    return TrackedObjects(
        stamp=0,
        ids=np.array(list(rows), dtype=np.int64),
        table=np.array(table).reshape(-1, len(TRACK_COLUMNS)),
    )


def test_a_car_waiting_before_the_shuttle_is_owed_the_right_of_way_until_it_leaves():
    order = ArrivalOrder(entries=(SIDE,), box=BOX)
    order.observe(10.0, _tracks({7: (7.0, -4.0, 0.0, 0.0)}))
    order.ego_stopped(12.0)
    assert order.owed() == [7]
    order.observe(13.0, _tracks({7: (7.0, 2.0, 0.0, 3.0)}))
    assert order.owed() == []
    assert order.box_occupied(_tracks({7: (7.0, 2.0, 0.0, 3.0)})) == 7


def test_a_car_arriving_after_the_shuttle_waits_for_it():
    order = ArrivalOrder(entries=(SIDE,), box=BOX)
    order.ego_stopped(10.0)
    order.observe(12.0, _tracks({8: (7.0, -4.0, 0.0, 0.0)}))
    assert order.owed() == []


def test_moving_traffic_passing_the_line_is_not_an_arrival():
    order = ArrivalOrder(entries=(SIDE,), box=BOX)
    order.observe(10.0, _tracks({9: (7.0, -4.0, 0.0, 5.0)}))
    order.ego_stopped(11.0)
    assert order.owed() == []


def test_a_lost_track_is_forgotten_after_the_timeout():
    order = ArrivalOrder(entries=(SIDE,), box=BOX, forget_s=1.5)
    order.observe(10.0, _tracks({7: (7.0, -4.0, 0.0, 0.0)}))
    order.ego_stopped(11.0)
    order.observe(11.0, _tracks({}))
    assert order.owed() == [7]
    order.observe(12.0, _tracks({}))
    assert order.owed() == []
