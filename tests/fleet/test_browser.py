"""End to end in a real headless browser: a rider requests a ride on the rider page, a scripted vehicle
client (standing in for the simulated shuttle) is assigned it and reports the pick-up, and the page
shows the rider picked up; then the operator's dashboard shows the shuttle and its emergency-stop
button stops it. Playwright drives Debian's Chromium (installed by scripts/ensure_chromium.sh)."""

from __future__ import annotations

import asyncio
import shutil
from pathlib import Path

import pytest

from lastmile.fleet.vehicle_client import VehicleClient
from tests.fleet.conftest import ServerProcess

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def _chromium() -> str:
    if CHROMIUM.exists():
        return str(CHROMIUM)
    found = shutil.which("chromium")
    if found is None:
        pytest.skip("Chromium not found at /usr/bin/chromium nor on PATH: run scripts/ensure_chromium.sh")
    return found


def test_rider_page_shows_the_ride_picked_up_by_the_shuttle(fresh_server: ServerProcess) -> None:
    from playwright.async_api import async_playwright, expect

    server = fresh_server
    chromium = _chromium()

    async def scenario() -> None:
        vehicle = VehicleClient(server.url, "shuttle-web", server.tokens["vehicle"])
        await vehicle.register()
        with server.client("operator") as op:
            assert (
                op.post("/api/vehicles/shuttle-web/command", json={"command": "start_service"}).status_code
                == 200
            )
        await vehicle.start()
        await vehicle.send_status(x_m=560.0, y_m=-6.5, yaw_rad=0.0, speed_mps=0.0, behaviour="dwell")
        async with async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = await browser.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            await page.goto(server.url + "/rider")
            await page.fill("#token", server.tokens["rider"])
            await page.click("#save-token")
            await expect(page.locator("#link-state")).to_have_text("live")
            await page.select_option("#origin", "S2")
            await page.select_option("#destination", "S4")
            await page.click("#request")
            state = page.locator("#ride-state")
            await expect(state).to_have_attribute("data-state", "assigned")
            await expect(page.locator("#ride-vehicle")).to_have_text("shuttle-web")
            assert await page.locator("#ride-eta").inner_text() != "—"
            await vehicle.wait_for(lambda v: any(a.kind == "pickup" for a in v.assignments.values()))
            pickup = next(a for a in vehicle.assignments.values() if a.kind == "pickup")
            assert pickup.stop_id == "S2"
            # The shuttle reaches S2's bay, opens its door and reports the pick-up.
            await vehicle.send_status(
                x_m=766.5, y_m=200.0, yaw_rad=1.57, speed_mps=0.0, behaviour="dwell", door="open"
            )
            assert await vehicle.complete(pickup.id) is True
            await expect(state).to_have_attribute("data-state", "picked_up")
            await expect(state).to_have_text("picked_up")
            assert await page.locator("#cancel").is_disabled()
            # The operator's dashboard shows the shuttle live and its emergency stop reaches the vehicle.
            op_page = await browser.new_page()
            op_page.on("pageerror", lambda exc: errors.append(str(exc)))
            await op_page.goto(server.url + "/")
            await op_page.fill("#token", server.tokens["operator"])
            await op_page.click("#save-token")
            row = op_page.locator('tr[data-vehicle="shuttle-web"]')
            await expect(row.locator(".state")).to_have_text("in_service")
            await expect(row).to_contain_text("dwell")
            # The vehicle's HMI (what its screens and autonomy light show) reaches the dashboard.
            hmi = {
                "cue": "yielding_pedestrian",
                "light": "amber",
                "front": "After you - please cross",
                "rear": "Stopping for pedestrians",
                "inside": "Giving way to pedestrians",
                "sound": "yield_chime",
            }
            await vehicle.send_status(
                x_m=766.5, y_m=200.0, yaw_rad=1.57, speed_mps=0.0, behaviour="dwell", door="open", hmi=hmi
            )
            await expect(row.locator(".hmi")).to_contain_text("After you - please cross")
            await expect(row.locator(".hmi")).to_contain_text("yielding_pedestrian")
            await expect(row.locator(".hmi")).to_have_attribute("data-light", "amber")
            await row.locator('button[data-command="emergency_stop"]').click()
            await expect(row.locator(".state")).to_have_text("emergency_stop")
            await vehicle.wait_for(lambda v: v.service == "emergency_stop")
            assert vehicle.stats.commands == ["emergency_stop"]
            assert errors == []
            await browser.close()
        await vehicle.stop()

    asyncio.run(scenario())
