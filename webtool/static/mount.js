(function () {
  "use strict";
  const $ = (id) => document.getElementById(id);
  const num = (id) => Number($(id).value);
  let proposed = null, timer = null, busy = false;

  function fmt(v, d) { return Number(v).toFixed(d); }

  function fill(st) {
    const a = st.angles;
    $("tilt").value = fmt(a.tilt_deg, 1); $("pan").value = fmt(a.pan_deg, 1); $("roll").value = fmt(a.roll_deg, 1);
    $("off-f").value = fmt(a.offset_m[0] * 100, 1); $("off-r").value = fmt(a.offset_m[1] * 100, 1);
    $("off-d").value = fmt(a.offset_m[2] * 100, 1); $("height").value = fmt(st.height_m, 1);
  }

  function show(st) {
    const f = st.footprint, h = fmt(st.height_m, 1);
    let t;
    const far = f.horizon ? "the horizon" : fmt(f.farthest_m, 1) + " m away";
    if (f.sees_ground === false) t = "With this tilt the camera looks at or above the horizon: it does not see the ground (a tilt over 90° points the camera upward)";
    else if (f.below) t = "At " + h + " m the camera sees the ground under the drone and up to " + far;
    else t = "At " + h + " m the camera sees the ground from " + fmt(f.nearest_m, 1) + " m to " + far + " (not right under the drone)";
    if (f.centre) t += "; the image centre falls " + fmt(f.centre[0], 2) + " m ahead, " + fmt(f.centre[1], 2) + " m right.";
    else t += "; the image centre is above the horizon.";
    $("ground-text").textContent = t;
    const bl = (st.blind || []).map((b) => b.layout + ": " + (!b.seen ? "never in the picture on the way down" : b.leaves_at_m === null ? "in view all the way down" : "out of the picture below " + fmt(b.leaves_at_m, 2) + " m") + " (straight down: " + (b.straight_down_leaves_at_m === null ? "in view all the way down" : fmt(b.straight_down_leaves_at_m, 2) + " m") + ")");
    $("blind-text").textContent = bl.length ? "Landing straight onto a brick, camera height above it where the brick leaves the picture (below it the autopilot lands blind, on its last estimate) — " + bl.join("; ") + "." : "";
    $("matrix").textContent = st.body_from_camera.map((r) => r.map((v) => fmt(v, 4).padStart(8)).join(" ")).join("\n");
    $("mount-file").textContent = st.file;
    $("save-msg").className = "msg";
    $("save-msg").textContent = st.saved ? "Saved." : (st.loaded_from ? "Not saved yet (read from " + st.loaded_from + ")." : "Not saved yet.");
  }

  function body() {
    return {angles: {tilt_deg: num("tilt"), pan_deg: num("pan"), roll_deg: num("roll"),
                     offset_m: [num("off-f") / 100, num("off-r") / 100, num("off-d") / 100]},
            height_m: num("height")};
  }

  async function call(url, opts) {
    const r = await fetch(url, opts);
    let js = null;
    try { js = await r.json(); } catch (e) { js = {detail: r.status + " " + r.statusText}; }
    if (!r.ok) throw new Error(js.detail || (r.status + " " + r.statusText));
    return js;
  }

  async function preview() {
    if (!$("mount-form").checkValidity()) { $("save-msg").className = "msg error"; $("save-msg").textContent = "Check the numbers: each field shows its range."; return; }
    try {
      show(await call("/api/mount/preview", {method: "POST", headers: {"content-type": "application/json"}, body: JSON.stringify(body())}));
    } catch (e) { $("save-msg").className = "msg error"; $("save-msg").textContent = e.message; }
  }

  function later() { clearTimeout(timer); timer = setTimeout(preview, 250); }

  async function save(ev) {
    ev.preventDefault();
    if (busy) return;
    busy = true;
    try {
      await preview();
      const st = await call("/api/mount/save", {method: "POST"});
      show(st);
      $("save-msg").textContent = "Saved to " + st.file + ". The live view uses it from its next start.";
    } catch (e) { $("save-msg").className = "msg error"; $("save-msg").textContent = e.message; }
    busy = false;
  }

  function measured(js) {
    const p = js.proposed;
    proposed = p;
    $("measure-msg").className = "msg";
    $("measure-msg").textContent = "Measured from " + js.pictures + " picture(s): tilt " + fmt(p.tilt_deg, 1) + "°, roll " + fmt(p.roll_deg, 1) + "°" +
      (js.pan_measured ? ", pan " + fmt(p.pan_deg, 1) + "°" : " (pan not measured: kept at " + fmt(p.pan_deg, 1) + "°)") + "; pictures agree within " + fmt(js.spread_deg, 2) + "°." +
      (js.pan_refused ? " Why no pan: " + js.pan_refused.replace(/^pan not measured: /, "") + "." : "");
    $("measure-lines").innerHTML = "";
    for (const line of js.lines) { const li = document.createElement("li"); li.textContent = line; $("measure-lines").appendChild(li); }
    $("use-measured").hidden = false;
  }

  function failed(e) {
    $("measure-msg").className = "msg error"; $("measure-msg").textContent = e.message;
    $("use-measured").hidden = true; proposed = null;
  }

  async function measureLive() {
    $("measure-msg").className = "msg"; $("measure-msg").textContent = "Measuring from the live camera…";
    $("measure-live").disabled = true;
    try {
      measured(await call("/api/mount/measure-live", {method: "POST", headers: {"content-type": "application/json"},
                                                      body: JSON.stringify({aligned: $("aligned").checked})}));
    } catch (e) { failed(e); }
    $("measure-live").disabled = false;
  }

  async function measureFiles() {
    const files = $("measure-files").files;
    if (!files.length) return;
    const fd = new FormData();
    for (const f of files) fd.append("files", f, f.name);
    $("measure-msg").className = "msg"; $("measure-msg").textContent = "Measuring " + files.length + " photo(s)…";
    try {
      measured(await call("/api/mount/measure?aligned=" + ($("aligned").checked ? "true" : "false"), {method: "POST", body: fd}));
    } catch (e) { failed(e); }
    $("measure-files").value = "";
  }

  function useMeasured() {
    if (!proposed) return;
    $("tilt").value = fmt(proposed.tilt_deg, 1); $("roll").value = fmt(proposed.roll_deg, 1); $("pan").value = fmt(proposed.pan_deg, 1);
    preview();
    $("measure-msg").textContent = "Angles taken over: check the preview, then save.";
  }

  async function start() {
    try {
      const st = await call("/api/mount");
      fill(st); show(st);
    } catch (e) { $("save-msg").className = "msg error"; $("save-msg").textContent = e.message; }
    try {
      const sc = await call("/api/mount/scene");
      $("preview-frame").src = sc.url;
    } catch (e) { $("ground-text").textContent = e.message; }
  }

  $("mount-form").addEventListener("input", later);
  $("mount-form").addEventListener("submit", save);
  $("measure-live").addEventListener("click", measureLive);
  $("measure-files").addEventListener("change", measureFiles);
  $("use-measured").addEventListener("click", useMeasured);
  start();
})();
