// Shared by the dashboard and the rider page: token, API calls, live snapshots, map drawing.
"use strict";

const Fleet = (() => {
  const tokenKey = "lastmile.token";
  const token = () => localStorage.getItem(tokenKey) || "";
  const setToken = (t) => localStorage.setItem(tokenKey, t.trim());
  // Text from the server (stop names come from the user's route file) goes into HTML escaped.
  const esc = (t) => String(t).replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);

  async function api(method, path, body) {
    const res = await fetch(path, {
      method,
      headers: { Authorization: "Bearer " + token(), "Content-Type": "application/json" },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    const text = await res.text();
    let data = null;
    try { data = text ? JSON.parse(text) : null; } catch (e) { data = text; }
    if (!res.ok) {
      const detail = data && data.detail ? (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail)) : text;
      throw new Error(res.status + ": " + detail);
    }
    return data;
  }

  // One live connection; reconnects after a drop so the page keeps updating.
  function live(onSnapshot, onState) {
    let ws = null;
    const open = () => {
      const proto = location.protocol === "https:" ? "wss" : "ws";
      ws = new WebSocket(`${proto}://${location.host}/ws/live?token=${encodeURIComponent(token())}`);
      ws.onopen = () => onState && onState("live");
      ws.onmessage = (ev) => onSnapshot(JSON.parse(ev.data));
      ws.onclose = (ev) => {
        onState && onState("disconnected (" + (ev.reason || ev.code) + ")");
        if (ev.code < 4000) setTimeout(open, 1000);
      };
    };
    open();
    return { close: () => ws && ws.close() };
  }

  // Map frame (metres, y up) to canvas pixels (y down), keeping the aspect ratio.
  function projector(canvas, bounds) {
    const [x0, y0, x1, y1] = bounds;
    const pad = 20, labels = 140;  // room on the right for stop names
    const s = Math.min((canvas.width - 2 * pad - labels) / (x1 - x0), (canvas.height - 2 * pad) / (y1 - y0));
    return (x, y) => [pad + (x - x0) * s, canvas.height - pad - (y - y0) * s];
  }

  function poly(ctx, P, pts, close) {
    ctx.beginPath();
    pts.forEach(([x, y], i) => { const [u, v] = P(x, y); i ? ctx.lineTo(u, v) : ctx.moveTo(u, v); });
    if (close) ctx.closePath();
  }

  const serviceColour = { in_service: "#1a7f37", suspended: "#b08800", emergency_stop: "#cf222e", out_of_service: "#6e7781" };

  function draw(canvas, map, snap, highlightVehicle) {
    const ctx = canvas.getContext("2d");
    const P = projector(canvas, map.bounds_m);
    ctx.fillStyle = "#f6f8fa";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    for (const a of map.areas) {
      ctx.fillStyle = a.subtype === "building" ? "#d0d7de" : "#dafbe1";
      poly(ctx, P, a.polygon, true); ctx.fill();
    }
    for (const l of map.lanelets) {
      ctx.fillStyle = l.subtype === "crosswalk" ? "#ffffff" : "#8c959f";
      poly(ctx, P, l.polygon, true); ctx.fill();
    }
    ctx.strokeStyle = "#0969da"; ctx.lineWidth = 1.5; ctx.setLineDash([6, 4]);
    poly(ctx, P, map.loop, true); ctx.stroke(); ctx.setLineDash([]);
    const waiting = {};
    (snap ? snap.stops : []).forEach((s) => { waiting[s.id] = s.waiting; });
    for (const s of map.stops) {
      const [u, v] = P(s.x_m, s.y_m);
      ctx.fillStyle = "#8250df"; ctx.fillRect(u - 6, v - 6, 12, 12);
      ctx.fillStyle = "#24292f"; ctx.font = "12px sans-serif";
      ctx.fillText(`${s.id} ${s.name}` + (waiting[s.id] ? ` (${waiting[s.id]} waiting)` : ""), u + 9, v - 8);
    }
    for (const vh of snap ? snap.vehicles : []) {
      if (vh.x_m === null) continue;
      const [u, v] = P(vh.x_m, vh.y_m);
      const yaw = vh.yaw_rad || 0;
      ctx.save(); ctx.translate(u, v); ctx.rotate(-yaw);
      ctx.fillStyle = serviceColour[vh.service] || "#000";
      ctx.beginPath(); ctx.moveTo(12, 0); ctx.lineTo(-8, 7); ctx.lineTo(-8, -7); ctx.closePath(); ctx.fill();
      if (vh.id === highlightVehicle) { ctx.strokeStyle = "#fb8500"; ctx.lineWidth = 3; ctx.stroke(); }
      ctx.restore();
      ctx.fillStyle = "#24292f";
      ctx.fillText(`${vh.id} ${vh.passengers}/${vh.capacity}`, u + 10, v + 16);
    }
  }

  function fmtEta(us) {
    if (us === null || us === undefined) return "—";
    return new Date(us / 1000).toLocaleTimeString();
  }

  // A full local date and time (the event log spans days): 2026-05-20 08:14:03.
  function fmtStamp(us) {
    const d = new Date(us / 1000), p = (n) => String(n).padStart(2, "0");
    return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())} ${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}`;
  }

  // The token is typed into a password field and never shown again: once accepted, the header says
  // who it belongs to (role and subject), and "change token" brings an empty field back.
  function tokenBox(el, onSave) {
    const input = el.querySelector("#token"), save = el.querySelector("#save-token");
    const change = el.querySelector("#change-token"), who = el.querySelector("#who");
    const editing = (on) => { input.hidden = !on; save.hidden = !on; change.hidden = on; };
    async function signedIn() {
      input.value = "";
      try {
        const w = await api("GET", "/api/whoami");
        who.textContent = `signed in as ${w.role} ${w.subject}`;
        editing(false);
      } catch (e) {
        who.textContent = "token not accepted";
        editing(true);
      }
    }
    save.onclick = () => { setToken(input.value); signedIn(); onSave(); };
    input.onkeydown = (ev) => { if (ev.key === "Enter") save.onclick(); };
    change.onclick = () => { editing(true); input.focus(); };
    if (token()) signedIn(); else editing(true);
  }

  return { api, live, draw, esc, token, setToken, fmtEta, fmtStamp, tokenBox };
})();
