(function () {
  "use strict";
  const $ = (id) => document.getElementById(id);
  const img = $("live-image");
  let readOnly = false, ws = null, retry = 500, prevUrl = null, gotFrame = false;

  function fmt(v, unit, d) { return (v === null || v === undefined) ? "–" : Number(v).toFixed(d) + unit; }

  function showState(msg) {
    const st = msg.status || {};
    const src = st.source || {};
    const state = src.state || (st.running ? "starting" : "stopped");
    const el = $("fig-source");
    el.textContent = state; el.className = "state " + state;
    $("imgbox").classList.toggle("lost", state === "lost");
    if (state === "lost") $("lost-note").textContent = "Camera lost — retrying" + (src.error ? " (" + src.error + ")" : "") + "…";
    $("fig-fps").textContent = fmt(st.fps, " fps", 1);
    $("fig-detect").textContent = fmt(st.detect_ms, " ms", 1);
    $("fig-latency").textContent = fmt(st.latency_ms, " ms", 1);
    const all = msg.bricks || [], held = all.filter((b) => !b.measured).length;
    $("fig-bricks").textContent = all.length + (held ? " (" + held + " held over)" : "");
    const fc = (st.sinks || []).filter((k) => String(k.sink).startsWith("mavlink:"));
    $("fig-fc-box").hidden = !fc.length;
    if (!fc.length) $("fc-panel").hidden = true;
    if (fc.length) {
      const k = fc[0];
      $("fig-fc").textContent = k.sent + " targets sent" + (k.held_not_sent ? ", " + k.held_not_sent + " frames without the target (nothing sent)" : "") + (k.lost ? ", " + k.lost + " not sent (link down)" : "") + (k.errors ? ", " + k.errors + " failed" : "");
      $("fc-note").textContent = k.down ? "Link down: " + k.down : k.note ? "No data from the autopilot: " + k.note : "";
      const bad = (k.check || []).filter((c) => c.status === "wrong" || c.status === "warn");
      $("fc-check-head").textContent = !k.vehicle ? "" : bad.length ? "Autopilot check (" + k.vehicle.autopilot + ", system " + k.vehicle.system + "), to fix:" : "Autopilot check (" + k.vehicle.autopilot + ", system " + k.vehicle.system + "): everything read is ok.";
      const list = $("fc-check");
      list.replaceChildren(...bad.map((c) => { const li = document.createElement("li"); li.textContent = c.item + ": " + c.text; return li; }));
      $("fc-panel").hidden = !k.down && !k.note && !k.vehicle;
    }
    const s = msg.stream || {};
    $("fig-stream").textContent = fmt(s.kbps, " kbit/s", 0);
    $("stream-note").title = "JPEG quality " + s.jpeg_quality + ", scale " + s.scale + ", share " + s.share_kbps + " kbit/s of " + st.bandwidth_kbps + ", " + st.viewers + " viewer(s)";
    if (st.target) $("target-spec").textContent = specLabel(st.target.spec);
    readOnly = msg.access === "viewer";
    $("access-note").textContent = readOnly ? "View-only link: you can watch but not change the target." : "";
    document.querySelectorAll(".target-btn").forEach((b) => { b.disabled = readOnly; });
    showBricks(msg.bricks || []);
  }

  // Targets named as people know them: "brick 3 of drick-aruco-pyramids", not "drick-aruco-pyramids:3".
  const trackNames = {};
  function brickName(b) {
    return b.instance !== null ? "brick " + b.instance + " of " + b.layout
                               : "a " + b.layout + " brick (seen as no. " + b.track + ")";
  }
  function specLabel(spec) {
    if (!spec) return "";
    if (spec === "nearest") return "the nearest brick";
    let m = /^track:(\d+)$/.exec(spec);
    if (m) return trackNames[m[1]] || "the brick seen as no. " + m[1];
    m = /^(.+):(\d+)$/.exec(spec);
    if (m) return "brick " + m[2] + " of " + m[1];
    return spec;
  }

  function cells(b) {
    const p = b.body_from_brick ? b.body_from_brick.tvec : [null, null, null];
    return [fmt(p[0], "", 2), fmt(p[1], "", 2), fmt(p[2], "", 2), fmt(b.distance, " m", 2),
            b.uncertainty || "–",
            fmt(b.yaw_deg, "°", 1) + (b.symmetric ? " ±180°" : ""),
            b.measured ? "now" : fmt(b.age * 1000, " ms ago", 0), b.method];
  }

  // Rows are kept and updated in place (a button must not move under a finger).
  function showBricks(bricks) {
    const body = $("bricks-body");
    const keep = new Set();
    if (!bricks.length) {
      body.innerHTML = '<tr><td colspan="10">No brick in view.</td></tr>';
      return;
    }
    body.querySelectorAll("tr:not([data-brick])").forEach((r) => r.remove());
    for (const b of bricks) {
      const name = b.layout + (b.instance !== null ? ":" + b.instance : " #" + b.track);
      const spec = b.instance !== null ? b.layout + ":" + b.instance : "track:" + b.track;
      keep.add(name);
      let row = body.querySelector('tr[data-brick="' + CSS.escape(name) + '"]');
      if (!row) {
        row = document.createElement("tr");
        row.dataset.brick = name;
        row.innerHTML = "<td></td>" + "<td></td>".repeat(8) +
          '<td><button type="button" class="target-btn">Make target</button></td>';
        row.querySelector("button").dataset.spec = spec;
        body.appendChild(row);
      }
      row.className = b.target ? "target" : "";
      const td = row.children;
      if (b.track !== undefined && b.track !== null) trackNames[b.track] = brickName(b);
      const label = brickName(b) + (b.target ? " (target)" : "");
      if (td[0].textContent !== label) td[0].textContent = label;
      cells(b).forEach((v, i) => { if (td[i + 1].textContent !== v) td[i + 1].textContent = v; });
      row.querySelector("button").disabled = readOnly;
    }
    body.querySelectorAll("tr[data-brick]").forEach((r) => { if (!keep.has(r.dataset.brick)) r.remove(); });
  }

  document.addEventListener("click", async (ev) => {
    const b = ev.target.closest(".target-btn");
    if (!b || readOnly) return;
    const r = await fetch("/api/live/target", {method: "POST", headers: {"content-type": "application/json"},
                                               body: JSON.stringify({spec: b.dataset.spec})});
    const js = await r.json().catch(() => ({}));
    $("target-msg").textContent = r.ok ? "Target: " + specLabel(js.target.spec) : "Not changed: " + (js.detail || r.status);
    if (r.ok) $("target-spec").textContent = specLabel(js.target.spec);
  });

  img.addEventListener("load", () => {
    if (prevUrl) URL.revokeObjectURL(prevUrl);
    prevUrl = img.src;
    gotFrame = true;
    img.dataset.frames = String(Number(img.dataset.frames || 0) + 1);
    if (ws && ws.readyState === 1) ws.send("ack");
  });

  function connect() {
    const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/api/live/ws";
    ws = new WebSocket(url);
    ws.binaryType = "blob";
    ws.onopen = () => { retry = 500; };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") { showState(JSON.parse(ev.data)); return; }
      img.src = URL.createObjectURL(ev.data);
    };
    ws.onclose = () => { setTimeout(connect, retry); retry = Math.min(retry * 2, 5000); };
  }
  connect();

  // The 3D view loads after the first camera image (the image matters most on a phone).
  let sceneAsked = false;
  function loadScene() {
    if (sceneAsked) return;
    sceneAsked = true;
    fetch("/api/live/scene").then((r) => r.ok ? r.json() : null).then((js) => {
      if (js && js.url) $("scene-frame").src = js.url;
    }).catch(() => { sceneAsked = false; });
  }
  img.addEventListener("load", loadScene, {once: true});
  setTimeout(loadScene, 8000);
})();
