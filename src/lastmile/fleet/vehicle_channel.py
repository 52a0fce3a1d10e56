"""What the dispatcher does with a vehicle's messages: status, acknowledgements, trips done, the seat
button, (re)connection; and the relay of infrastructure presence to every connected vehicle."""

from __future__ import annotations

from typing import Any

from sqlalchemy import Connection, insert, update

from lastmile.fleet import storage as db
from lastmile.fleet.service_core import ServiceCore
from lastmile.fleet.service_records import now_us
from lastmile.fleet.service_views import plan_message


class VehicleChannel(ServiceCore):
    """The vehicle side of the dispatcher (see ``ServiceCore`` for the state and its rules)."""

    def resume_messages(self, vehicle_id: str) -> list[dict[str, Any]]:
        """What a (re)connecting vehicle must hear: its service state and every trip not yet done."""
        v = self.vehicles[vehicle_id]
        msgs: list[dict[str, Any]] = [{"type": "service", "service": v.service}]
        for visit in v.plan:
            for item in visit.items:
                msgs.append({"type": "assignment", "trip": self.trips[item.trip_id].message()})
        msgs.append(plan_message(v))
        self._plan_sent[vehicle_id] = v.plan
        return msgs

    def broadcast_presence(self, node_id: str, crosswalk: int, present: bool, captured_us: int) -> int:
        """Relay an infrastructure node's pedestrian presence to every connected vehicle, as it came;
        returns how many vehicles it was queued to."""
        msg = {
            "type": "infrastructure",
            "node_id": node_id,
            "crosswalk": crosswalk,
            "present": present,
            "captured_us": captured_us,
        }
        self.presence[node_id] = {**msg, "received_us": now_us()}
        sent = 0
        for v in self.vehicles.values():
            if v.connected:
                self.push(v.id, msg)
                sent += 1
        return sent

    def vehicle_status(self, vehicle_id: str, msg: dict[str, Any]) -> None:
        """A status report: memory now, database without waiting (a lost status is replaced by the next)."""
        v = self.vehicles[vehicle_id]
        for key in ("x_m", "y_m", "yaw_rad", "speed_mps", "behaviour", "health", "passengers", "door"):
            if key in msg:
                setattr(v, key, msg[key])
        if msg.get("hmi") is not None:
            v.hmi = dict(msg["hmi"])
        if v.x_m is not None and v.y_m is not None:
            v.route_s_m = self.route.project_s(v.x_m, v.y_m, v.route_s_m)
        v.last_status_us = now_us()
        values = {
            k: getattr(v, k)
            for k in (
                "x_m",
                "y_m",
                "yaw_rad",
                "speed_mps",
                "route_s_m",
                "behaviour",
                "health",
                "passengers",
                "door",
                "last_status_us",
            )
        }
        self.writer.submit_nowait(
            lambda conn: conn.execute(
                update(db.vehicles).where(db.vehicles.c.id == vehicle_id).values(**values)
            )
        )
        self._touch()

    async def trip_ack(self, vehicle_id: str, trip_id: int) -> None:
        trip = self.trips.get(trip_id)
        if trip is None or trip.vehicle_id != vehicle_id or trip.state != "pending":
            return
        trip.state = "acked"
        await self.writer.submit(
            lambda conn: conn.execute(update(db.trips).where(db.trips.c.id == trip_id).values(state="acked"))
        )

    async def trip_done(self, vehicle_id: str, trip_id: int) -> bool:
        """The vehicle did a trip (picked up, dropped off, called at the stop). False if already known."""
        trip = self.trips.get(trip_id)
        if trip is None or trip.vehicle_id != vehicle_id:
            return False
        self._drop_from_plan(trip)
        t = now_us()
        ride = self.rides.get(trip.request_id) if trip.request_id else None
        ride_values: dict[str, Any] = {}
        if ride is not None and trip.kind == "pickup":
            ride_values = {"state": "picked_up", "picked_up_us": t}
        elif ride is not None and trip.kind == "dropoff":
            ride_values = {"state": "dropped_off", "dropped_off_us": t, "closed_us": t}
        if ride is not None and ride_values:
            ride.update(ride_values)
            if ride["state"] == "dropped_off":
                self.rides.pop(ride["id"], None)
        v = self.vehicles[vehicle_id]
        renumber = self._visit_rows(v)
        kind_event = {"pickup": "picked_up", "dropoff": "dropped_off"}.get(trip.kind, f"{trip.kind}_served")

        def op(conn: Connection) -> None:
            conn.execute(update(db.trips).where(db.trips.c.id == trip_id).values(state="done", done_us=t))
            if ride_values and trip.request_id:
                conn.execute(
                    update(db.ride_requests)
                    .where(db.ride_requests.c.id == trip.request_id)
                    .values(**ride_values)
                )
            self._renumber(conn, renumber)
            self._event(conn, kind_event, vehicle_id, trip.request_id, trip_id=trip_id, stop_id=trip.stop_id)

        await self.writer.submit(op)
        await self._drain()
        self._touch()
        return True

    async def seat_button(self, vehicle_id: str, seat: int) -> dict[str, Any]:
        """A passenger asks to get off: a seat_stop at the next stop the shuttle can still stop at."""
        v = self.vehicles[vehicle_id]
        s = self._vehicle_s(v)
        stop_id, ahead_m = self.planner.seat_button_stop(s, v.speed_mps or 0.0)
        at = self.planner.first_ahead_m(s, stop_id)
        if at < ahead_m - 1.0:  # the stop is "at" the vehicle but it cannot stop there any more
            at += self.route.length_m
        existing = next(
            (
                i
                for visit, d in zip(v.plan, self.planner.unrolled_m(v.plan, s), strict=True)
                if abs(d - at) < 1e-6
                for i in visit.items
                if i.kind == "seat_stop"
            ),
            None,
        )
        if existing is not None:
            return self.trips[existing.trip_id].message()
        trip = self._new_trip(v.id, "seat_stop", stop_id, seats=0)
        v.plan = self.planner.insert(v.plan, s, at, stop_id, trip.plan_item())
        row = trip.row()
        renumber = self._visit_rows(v)

        def op(conn: Connection) -> None:
            conn.execute(insert(db.trips).values(**row))
            self._renumber(conn, renumber)
            self._event(conn, "seat_button", vehicle_id, None, seat=seat, stop_id=stop_id)

        await self.writer.submit(op)
        self.push(vehicle_id, {"type": "assignment", "trip": trip.message()})
        self._touch()
        return trip.message()

    def set_connected(self, vehicle_id: str, connected: bool) -> None:
        self.vehicles[vehicle_id].connected = connected
        self._touch()
