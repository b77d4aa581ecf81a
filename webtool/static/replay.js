(function () {
  "use strict";
  const $ = (id) => document.getElementById(id);
  let dragging = false, timer = null, sceneAsked = false;
  const HOWTO = "No recordings yet: make one with “drovisio mission simulate wall-2-courses " +
    "--record missions/demo”, then start “drovisio serve --replay-dir missions”.";
  const fmtT = (t) => (t === null || t === undefined) ? "–" : Number(t).toFixed(1) + " s";

  async function api(path, body) {
    const opt = body === undefined ? {} : {method: "POST", headers: {"content-type": "application/json"},
                                            body: JSON.stringify(body)};
    const r = await fetch("/api/replay/" + path, opt);
    const js = await r.json().catch(() => ({}));
    if (!r.ok) throw new Error(js.detail || ("HTTP " + r.status));
    return js;
  }

  function show(st) {
    const on = !!st.loaded;
    ["replay-play", "replay-pause", "replay-speed", "replay-slider"].forEach((id) => { $(id).disabled = !on; });
    if (!on) return;
    $("replay-time").textContent = fmtT(st.t);
    $("replay-duration").textContent = fmtT(st.duration);
    const sl = $("replay-slider");
    sl.max = String(st.duration);
    if (!dragging) sl.value = String(st.t);
    $("replay-state").textContent = st.state;
    $("replay-placed").textContent = st.placed.length + " of " + st.bricks_total;
    $("replay-holding").textContent = st.holding ? "(carrying " + st.holding + ")" : "";
    $("replay-scene-note").textContent = st.note || "";
    $("replay-play").textContent = st.playing ? "Playing…" : "Play";
    $("replay-speed").value = String(st.speed);
    const ol = $("replay-events");
    const items = st.last_events.map((e) => fmtT(e.t) + ": " + e.text);
    if (ol.dataset.key !== items.join("|")) {
      ol.dataset.key = items.join("|");
      ol.innerHTML = "";
      items.slice().reverse().forEach((s) => { const li = document.createElement("li"); li.textContent = s; ol.appendChild(li); });
    }
  }

  async function poll() {
    try { show(await api("state")); } catch (e) { /* keep polling */ }
    timer = setTimeout(poll, 250);
  }

  async function listRuns() {
    try {
      const js = await api("runs");
      const sel = $("replay-run");
      sel.innerHTML = "";
      js.runs.filter((r) => r.ok).forEach((r) => {
        const o = document.createElement("option");
        o.value = r.name;
        o.textContent = r.name + " — " + r.scenario + ", " + r.bricks + " brick(s), " + fmtT(r.duration_s) + ", " + r.outcome;
        sel.appendChild(o);
      });
      if (!sel.options.length) {
        sel.innerHTML = '<option value="">(none)</option>';
        $("replay-msg").textContent = HOWTO;
        $("replay-load").disabled = true;
      }
    } catch (e) {
      $("replay-msg").textContent = HOWTO;
      $("replay-load").disabled = true;
    }
  }

  function loadScene() {
    if (sceneAsked) return;
    sceneAsked = true;
    api("scene").then((js) => { $("replay-frame").src = js.url; }).catch(() => { sceneAsked = false; });
  }

  async function act(path, body) {
    try { show(await api(path, body)); $("replay-msg").textContent = ""; }
    catch (e) { $("replay-msg").textContent = "Not done: " + e.message; }
  }

  $("replay-load").addEventListener("click", async () => {
    const name = $("replay-run").value;
    if (!name) return;
    await act("load", {name: name});
    loadScene();
    if (!timer) poll();
  });
  $("replay-play").addEventListener("click", () => act("play", {}));
  $("replay-pause").addEventListener("click", () => act("pause", {}));
  $("replay-speed").addEventListener("change", (ev) => act("speed", {x: Number(ev.target.value)}));
  const sl = $("replay-slider");
  sl.addEventListener("input", () => { dragging = true; $("replay-time").textContent = fmtT(sl.value); });
  sl.addEventListener("change", async () => { await act("seek", {t: Number(sl.value)}); dragging = false; });

  listRuns();
  api("state").then((st) => { if (st.loaded) { show(st); loadScene(); poll(); } }).catch(() => {});
})();
