(function () {
  "use strict";
  const $ = (id) => document.getElementById(id);
  const fmt = (v, unit, d) => (v === null || v === undefined) ? "–" : Number(v).toFixed(d) + unit;

  const LABELS = ["State", "Frame rate", "Latency", "Bricks", "Target", "Camera", "Web tool"];

  function cell(text) { const td = document.createElement("td"); td.textContent = text; return td; }

  function targetText(t) {
    if (!t) return "–";
    const name = t.layout + (t.instance === null || t.instance === undefined ? "" : " #" + t.instance);
    if (!Array.isArray(t.tvec)) return name;
    const d = Math.hypot(t.tvec[0], t.tvec[1], t.tvec[2]);
    return name + " at " + d.toFixed(2) + " m";
  }

  function row(d, now) {
    const tr = document.createElement("tr");
    tr.className = d.state;
    tr.dataset.drone = d.drone_id;
    const name = document.createElement("th"); name.scope = "row"; name.textContent = d.drone_id;
    tr.appendChild(name);
    const st = document.createElement("td"); const badge = document.createElement("span");
    badge.className = "state " + d.state; badge.textContent = d.state; st.appendChild(badge);
    tr.appendChild(st);
    tr.appendChild(cell(d.state === "live" ? fmt(d.fps, " fps", 1) : "–"));
    tr.appendChild(cell(fmt(d.latency_ms_p50, " ms", 0) + " / " + fmt(d.latency_ms_p90, " ms", 0)));
    tr.appendChild(cell(String(d.bricks)));
    const tgt = cell(targetText(d.target)); tgt.className = "target"; tr.appendChild(tgt);
    const imgCell = document.createElement("td");
    if (d.has_image) {
      const img = document.createElement("img");
      img.alt = "Camera of " + d.drone_id;
      img.src = "/api/fleet/drones/" + encodeURIComponent(d.drone_id) + "/image.jpg?t=" + Math.floor(now / 2000);
      imgCell.appendChild(img);
    } else imgCell.textContent = "–";
    tr.appendChild(imgCell);
    const web = document.createElement("td");
    const url = d.info && d.info.web;
    if (typeof url === "string" && /^https?:\/\//.test(url)) {
      const a = document.createElement("a"); a.href = url; a.textContent = "Open"; a.rel = "noopener";
      web.appendChild(a);
    } else web.textContent = "–";
    tr.appendChild(web);
    [...tr.querySelectorAll("td")].forEach((td, i) => { td.dataset.label = LABELS[i]; });
    return tr;
  }

  async function poll() {
    try {
      const r = await fetch("/api/fleet/status", { cache: "no-store" });
      if (r.ok) {
        const js = await r.json();
        const now = Date.now();
        $("fleet-empty").hidden = js.drones.length > 0;
        $("fleet-table").hidden = js.drones.length === 0;
        $("fleet-rows").replaceChildren(...js.drones.map((d) => row(d, now)));
        $("lost-after").textContent = String(js.lost_after_s);
        $("fleet-error").hidden = !js.error;
        $("fleet-error").textContent = js.error || "";
      }
    } catch (e) { /* the station restarts: the next poll tells */ }
    setTimeout(poll, 500);
  }

  async function scene() {
    try {
      const r = await fetch("/api/fleet/scene", { cache: "no-store" });
      if (r.ok) { const js = await r.json(); if (js.url) $("scene-frame").src = js.url; }
    } catch (e) { /* no 3D view */ }
  }

  poll();
  scene();
})();
