"""End to end in a real headless browser: a rider requests a ride on the rider page, a scripted vehicle
client (standing in for the simulated shuttle) is assigned it and reports the pick-up, and the page
shows the rider picked up; then the operator's dashboard shows the shuttle and its emergency-stop
button stops it. Playwright drives Debian's Chromium (installed by scripts/ensure_chromium.sh)."""

from __future__ import annotations

import asyncio
import re
import shutil
from collections.abc import Callable
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


async def _until(condition: Callable[[], bool], timeout_s: float = 10.0) -> None:
    for _ in range(int(timeout_s / 0.05)):
        if condition():
            return
        await asyncio.sleep(0.05)
    raise AssertionError("condition not met within the timeout")


def test_rider_page_shows_the_ride_picked_up_by_the_shuttle(fresh_server: ServerProcess) -> None:
    from playwright.async_api import Dialog, async_playwright, expect

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
            with server.client("operator") as op:
                extra = [
                    op.post("/api/rides", json={"origin": "S3", "destination": "S1"}).json()["id"]
                    for _ in range(60)
                ]
                op.delete(f"/api/rides/{extra[0]}").raise_for_status()
            op_page = await browser.new_page()
            op_page.on("pageerror", lambda exc: errors.append(str(exc)))
            api_calls: list[str] = []
            op_page.on(
                "request", lambda req: api_calls.append(req.url.split("?")[0].removeprefix(server.url))
            )
            await op_page.clock.install()  # the 10 s refresh is run by fast-forwarding below
            await op_page.goto(server.url + "/")
            token_box = op_page.locator("#token")
            assert await token_box.get_attribute("type") == "password"
            await op_page.fill("#token", server.tokens["operator"])
            await op_page.click("#save-token")
            # The token is out of sight once accepted: the header names who is signed in instead.
            await expect(op_page.locator("#who")).to_have_text("signed in as operator operator")
            await expect(token_box).to_be_hidden()
            assert server.tokens["operator"] not in await op_page.content()
            assert await token_box.input_value() == ""
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
            # Every ride, a page at a time (main showed the first 50 of the snapshot and no more).
            await expect(op_page.locator("#rides-range")).to_have_text("1–25 of 61")
            await expect(op_page.locator("#rides tbody tr")).to_have_count(25)
            await op_page.click("#rides-older")
            await op_page.click("#rides-older")
            await expect(op_page.locator("#rides-range")).to_have_text("51–61 of 61")
            await expect(op_page.locator("#rides-older")).to_be_disabled()
            await op_page.select_option("#ride-filter-state", "cancelled")
            await expect(op_page.locator("#rides-range")).to_have_text("1–1 of 1")
            await expect(op_page.locator(f'#rides tr[data-ride="{extra[0]}"]')).to_be_visible()
            await op_page.select_option("#ride-filter-state", "")
            await op_page.select_option("#ride-filter-stop", "S2")
            await expect(op_page.locator("#rides-range")).to_have_text("1–1 of 1")  # the rider's S2->S4
            # Events carry their date, not only a time of day.
            await expect(op_page.locator("#events .stamp").first).to_have_text(
                re.compile(r"^\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}$")
            )
            # Ten-second refreshes fetch the events again but never the map again.
            await op_page.clock.fast_forward("00:25")
            await _until(lambda: api_calls.count("/api/events") > 1)
            assert api_calls.count("/api/map") == 1
            # E-STOP stands apart (its own column, its own style) and asks first; cancelling does nothing.
            estop = row.locator('.emergency button[data-command="emergency_stop"]')
            assert await estop.get_attribute("class") == "estop"
            assert (
                await row.locator('button[data-command="release_emergency_stop"]').get_attribute("class")
                == "release"
            )
            assert await row.locator('.controls button[data-command="emergency_stop"]').count() == 0
            dialogs: list[str] = []

            async def dismiss(dialog: Dialog) -> None:
                dialogs.append(dialog.message)
                await dialog.dismiss()

            op_page.once("dialog", dismiss)
            await estop.click()
            await _until(lambda: len(dialogs) == 1)
            assert "EMERGENCY STOP shuttle shuttle-web?" in dialogs[0]
            await vehicle.sync()
            assert vehicle.service == "in_service" and vehicle.stats.commands == []

            async def accept(dialog: Dialog) -> None:
                dialogs.append(dialog.message)
                await dialog.accept()

            op_page.once("dialog", accept)
            await estop.click()
            await expect(row.locator(".state")).to_have_text("emergency_stop")
            await vehicle.wait_for(lambda v: v.service == "emergency_stop")
            assert vehicle.stats.commands == ["emergency_stop"]
            assert errors == []
            await browser.close()
        await vehicle.stop()

    asyncio.run(scenario())
