"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  // Vehicles' HMI texts arrive from the vehicles: shown as text, never as markup.
  const esc = Fleet.esc;
  let map = null, snap = null, link = null;
  const err = (e) => { $("op-error").textContent = e ? String(e.message || e) : ""; };
  const RIDES_PAGE = 25;
  const rides = { offset: 0, total: 0, loadedAt: 0, timer: null };

  async function command(id, cmd) {
    try { await Fleet.api("POST", `/api/vehicles/${id}/command`, { command: cmd }); err(null); } catch (e) { err(e); }
  }

  // Safety commands ask first: an emergency stop brakes a shuttle with riders on board where it is,
  // and a release lets it be started again.
  const CONFIRM = {
    emergency_stop: (id) => `EMERGENCY STOP shuttle ${id}?\n\nIt brakes to a stop where it is; riders not yet on board are re-planned.`,
    release_emergency_stop: (id) => `Release the emergency stop of shuttle ${id}?\n\nIt stays suspended until service is started.`,
  };

  function button(label, cmd, id, cls) {
    const b = document.createElement("button");
    b.textContent = label; b.dataset.command = cmd;
    if (cls) b.className = cls;
    b.onclick = () => { if (!CONFIRM[cmd] || window.confirm(CONFIRM[cmd](id))) command(id, cmd); };
    return b;
  }

  function renderVehicles() {
    const vb = $("vehicles").querySelector("tbody");
    vb.innerHTML = "";
    for (const v of snap.vehicles) {
      const tr = document.createElement("tr");
      tr.dataset.vehicle = v.id;
      tr.innerHTML = `<td>${esc(v.id)}</td><td class="state">${v.service}</td><td>${v.connected ? "up" : "down"}</td>` +
        `<td>${v.speed_mps === null ? "—" : (v.speed_mps * 3.6).toFixed(1) + " km/h"}</td><td>${esc(v.behaviour || "—")}</td>` +
        `<td>${esc(v.health || "—")}</td><td>${v.passengers}/${v.capacity}</td><td>${esc(v.door || "—")}</td>` +
        `<td class="hmi" data-light="${v.hmi ? esc(v.hmi.light) : ""}"><span class="light"></span>${v.hmi ? `${esc(v.hmi.front)} · ${esc(v.hmi.rear)} (${esc(v.hmi.cue)})` : "—"}</td><td class="controls"></td><td class="emergency"></td>`;
      const controls = tr.querySelector(".controls");
      controls.appendChild(button("start", "start_service", v.id));
      controls.appendChild(button("suspend", "suspend_service", v.id));
      controls.appendChild(button("release e-stop", "release_emergency_stop", v.id, "release"));
      tr.querySelector(".emergency").appendChild(button("E-STOP", "emergency_stop", v.id, "estop"));
      vb.appendChild(tr);
    }
  }

  function keepOptions(sel, values) {
    const keep = sel.value, first = sel.options[0] && sel.options[0].value === "" ? sel.options[0].outerHTML : "";
    sel.innerHTML = first + values.map((x) => `<option>${esc(x)}</option>`).join("");
    if (keep && values.includes(keep)) sel.value = keep;
  }

  function render() {
    if (map) Fleet.draw($("map"), map, snap);
    if (!snap) return;
    renderVehicles();
    keepOptions($("run-vehicle"), snap.vehicles.map((v) => v.id));
    keepOptions($("ride-filter-vehicle"), snap.vehicles.map((v) => v.id));
    $("queued").textContent = `(${snap.queued} queued)`;
    // Snapshots come whenever anything changes: reload the open page of the ride log at most every 2 s.
    if (!rides.timer) rides.timer = setTimeout(loadRides, Math.max(0, 2000 - (Date.now() - rides.loadedAt)));
  }

  // The ride log: every ride ever requested, newest first, a page at a time, filtered on the server.
  async function loadRides() {
    rides.timer = null; rides.loadedAt = Date.now();
    const q = new URLSearchParams({ offset: rides.offset, limit: RIDES_PAGE });
    for (const [key, id] of [["state", "ride-filter-state"], ["stop", "ride-filter-stop"], ["vehicle_id", "ride-filter-vehicle"]]) {
      if ($(id).value) q.set(key, $(id).value);
    }
    try {
      const page = await Fleet.api("GET", "/api/ride-log?" + q);
      rides.total = page.total;
      $("rides").querySelector("tbody").innerHTML = page.rides.map((r) =>
        `<tr data-ride="${esc(r.id)}"><td>${esc(r.id.slice(-8))}</td><td>${Fleet.fmtStamp(r.created_us)}</td><td>${esc(r.origin)}</td><td>${esc(r.destination)}</td><td>${r.seats}</td>` +
        `<td>${r.state}</td><td>${esc(r.vehicle_id || "—")}</td><td>${Fleet.fmtEta(r.eta_pickup_us)}</td></tr>`).join("");
      const last = rides.offset + page.rides.length;
      $("rides-range").textContent = page.total ? `${rides.offset + 1}–${last} of ${page.total}` : "no rides";
      $("rides-newer").disabled = rides.offset === 0;
      $("rides-older").disabled = last >= page.total;
    } catch (e) { err(e); }
  }

  const reloadRides = () => { rides.offset = 0; loadRides(); };
  for (const id of ["ride-filter-state", "ride-filter-stop", "ride-filter-vehicle"]) $(id).onchange = reloadRides;
  $("rides-newer").onclick = () => { rides.offset = Math.max(0, rides.offset - RIDES_PAGE); loadRides(); };
  $("rides-older").onclick = () => { rides.offset += RIDES_PAGE; loadRides(); };

  // The map and the timetable do not change while the server runs: fetched once per sign-in.
  async function loadOnce() {
    try {
      map = await Fleet.api("GET", "/api/map");
      keepOptions($("ride-filter-stop"), map.stops.map((s) => s.id));
      const tt = await Fleet.api("GET", "/api/timetable");
      keepOptions($("run-id"), [...new Set(tt.map((e) => e.run_id))]);
      err(null);
    } catch (e) { err(e); }
    render();
    loadRides();
  }

  // Recorded runs and the event log change: refreshed every 10 s.
  async function loadChanging() {
    try {
      const runs = await Fleet.api("GET", "/api/runs");
      $("runs").innerHTML = "";
      for (const r of runs) {
        const li = document.createElement("li");
        const b = document.createElement("button");
        b.textContent = "download";
        b.onclick = async () => {
          const res = await fetch(`/api/runs/${encodeURIComponent(r.name)}/archive`, { headers: { Authorization: "Bearer " + Fleet.token() } });
          const url = URL.createObjectURL(await res.blob());
          const a = document.createElement("a"); a.href = url; a.download = r.name + ".zip"; a.click();
        };
        li.textContent = `${r.name} (${r.files.length} files, ${(r.bytes / 1024).toFixed(0)} KiB) `;
        li.appendChild(b);
        $("runs").appendChild(li);
      }
      const ev = await Fleet.api("GET", "/api/events?newest_first=true&limit=50");
      $("events").querySelector("tbody").innerHTML = ev.map((e) =>
        `<tr><td class="stamp">${Fleet.fmtStamp(e.stamp_us)}</td><td>${esc(e.kind)}</td><td>${esc(e.vehicle_id || "")}</td><td>${esc((e.request_id || "").slice(-8))}</td></tr>`).join("");
    } catch (e) { err(e); }
  }

  function start() {
    if (link) link.close();
    loadOnce();
    loadChanging();
    link = Fleet.live((s) => { snap = s; render(); }, (st) => { $("link-state").textContent = st; });
  }

  $("register").onclick = async () => {
    try { await Fleet.api("POST", "/api/vehicles", { id: $("new-vehicle").value }); err(null); } catch (e) { err(e); }
  };
  $("assign-run").onclick = async () => {
    try { await Fleet.api("POST", `/api/vehicles/${$("run-vehicle").value}/timetable-run`, { run_id: $("run-id").value }); err(null); } catch (e) { err(e); }
  };
  Fleet.tokenBox($("token-box"), start);
  setInterval(() => { if (Fleet.token()) loadChanging(); }, 10000);
  if (Fleet.token()) start();
})();
