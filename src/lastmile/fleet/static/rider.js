"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  let map = null, snap = null, ride = null, link = null;
  const err = (e) => { $("rider-error").textContent = e ? String(e.message || e) : ""; };

  function show() {
    $("ride-state").textContent = ride ? ride.state : "none";
    $("ride-state").dataset.state = ride ? ride.state : "none";
    $("ride-vehicle").textContent = ride && ride.vehicle_id ? ride.vehicle_id : "—";
    $("ride-eta").textContent = ride ? Fleet.fmtEta(ride.eta_pickup_us) : "—";
    $("ride-reason").textContent = ride && ride.reason ? ride.reason : "";
    $("cancel").disabled = !ride || !["waiting", "assigned"].includes(ride.state);
    if (map) Fleet.draw($("map"), map, snap, ride ? ride.vehicle_id : null);
  }

  async function refreshRide() {
    if (!ride) return;
    try { ride = await Fleet.api("GET", `/api/rides/${ride.id}`); } catch (e) { err(e); }
    show();
  }

  function onSnapshot(s) {
    snap = s;
    const mine = ride && s.rides.find((r) => r.id === ride.id);
    if (mine) ride = mine;
    else if (ride && ["waiting", "assigned", "picked_up"].includes(ride.state)) refreshRide();
    show();
  }

  async function start() {
    try {
      map = await Fleet.api("GET", "/api/map");
      const opts = map.stops.map((s) => `<option value="${Fleet.esc(s.id)}">${Fleet.esc(s.id)} ${Fleet.esc(s.name)}</option>`).join("");
      $("origin").innerHTML = opts; $("destination").innerHTML = opts;
      $("destination").selectedIndex = 1;
      err(null);
    } catch (e) { err(e); return; }
    if (link) link.close();
    link = Fleet.live(onSnapshot, (st) => { $("link-state").textContent = st; });
    show();
  }

  $("request").onclick = async () => {
    try {
      ride = await Fleet.api("POST", "/api/rides", {
        origin: $("origin").value, destination: $("destination").value, seats: Number($("seats").value),
      });
      err(null);
    } catch (e) { err(e); }
    show();
  };
  $("cancel").onclick = async () => {
    try { ride = await Fleet.api("DELETE", `/api/rides/${ride.id}`); err(null); } catch (e) { err(e); }
    show();
  };
  Fleet.tokenBox($("token-box"), start);
  if (Fleet.token()) start();
})();
