"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  // Vehicles' HMI texts arrive from the vehicles: shown as text, never as markup.
  const esc = (t) => String(t).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
  let map = null, snap = null, link = null;
  const err = (e) => { $("op-error").textContent = e ? String(e.message || e) : ""; };

  async function command(id, cmd) {
    try { await Fleet.api("POST", `/api/vehicles/${id}/command`, { command: cmd }); err(null); } catch (e) { err(e); }
  }

  function render() {
    if (map) Fleet.draw($("map"), map, snap);
    if (!snap) return;
    const vb = $("vehicles").querySelector("tbody");
    vb.innerHTML = "";
    for (const v of snap.vehicles) {
      const tr = document.createElement("tr");
      tr.dataset.vehicle = v.id;
      tr.innerHTML = `<td>${v.id}</td><td class="state">${v.service}</td><td>${v.connected ? "up" : "down"}</td>` +
        `<td>${v.speed_mps === null ? "—" : (v.speed_mps * 3.6).toFixed(1) + " km/h"}</td><td>${v.behaviour || "—"}</td>` +
        `<td>${v.health || "—"}</td><td>${v.passengers}/${v.capacity}</td><td>${v.door || "—"}</td>` +
        `<td class="hmi" data-light="${v.hmi ? esc(v.hmi.light) : ""}"><span class="light"></span>${v.hmi ? `${esc(v.hmi.front)} · ${esc(v.hmi.rear)} (${esc(v.hmi.cue)})` : "—"}</td><td></td>`;
      const cell = tr.lastChild;
      for (const [label, cmd] of [["start", "start_service"], ["suspend", "suspend_service"], ["E-STOP", "emergency_stop"], ["release", "release_emergency_stop"]]) {
        const b = document.createElement("button");
        b.textContent = label; b.dataset.command = cmd; b.onclick = () => command(v.id, cmd);
        cell.appendChild(b);
      }
      vb.appendChild(tr);
    }
    const sel = $("run-vehicle"), keep = sel.value;
    sel.innerHTML = snap.vehicles.map((v) => `<option>${v.id}</option>`).join("");
    if (keep) sel.value = keep;
    $("queued").textContent = `(${snap.queued} queued)`;
    const rb = $("rides").querySelector("tbody");
    rb.innerHTML = snap.rides.slice(0, 50).map((r) =>
      `<tr><td>${r.id.slice(-8)}</td><td>${r.origin}</td><td>${r.destination}</td><td>${r.seats}</td>` +
      `<td>${r.state}</td><td>${r.vehicle_id || "—"}</td><td>${Fleet.fmtEta(r.eta_pickup_us)}</td></tr>`).join("");
  }

  async function loadStatic() {
    try {
      map = await Fleet.api("GET", "/api/map");
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
      const tt = await Fleet.api("GET", "/api/timetable");
      const runIds = [...new Set(tt.map((e) => e.run_id))];
      $("run-id").innerHTML = runIds.map((r) => `<option>${r}</option>`).join("");
      const ev = await Fleet.api("GET", "/api/events?limit=50");
      $("events").querySelector("tbody").innerHTML = ev.reverse().map((e) =>
        `<tr><td>${new Date(e.stamp_us / 1000).toLocaleTimeString()}</td><td>${e.kind}</td><td>${e.vehicle_id || ""}</td></tr>`).join("");
      err(null);
    } catch (e) { err(e); }
    render();
  }

  function start() {
    if (link) link.close();
    loadStatic();
    link = Fleet.live((s) => { snap = s; render(); }, (st) => { $("link-state").textContent = st; });
  }

  $("register").onclick = async () => {
    try { await Fleet.api("POST", "/api/vehicles", { id: $("new-vehicle").value }); err(null); } catch (e) { err(e); }
  };
  $("assign-run").onclick = async () => {
    try { await Fleet.api("POST", `/api/vehicles/${$("run-vehicle").value}/timetable-run`, { run_id: $("run-id").value }); err(null); } catch (e) { err(e); }
  };
  Fleet.tokenBox($("token-box"), start);
  setInterval(loadStatic, 10000);
  if (Fleet.token()) start();
})();
