(() => {
  "use strict";
  const API = "/api/designer";
  let state = null;
  let version = -1;
  const $ = (sel) => document.querySelector(sel);
  const $$ = (sel) => Array.from(document.querySelectorAll(sel));

  function showError(msg) {
    const box = $("#error");
    box.textContent = msg;
    box.hidden = !msg;
    if (msg) box.scrollIntoView({ block: "nearest" });
  }

  async function api(path, opts = {}) {
    const init = { method: opts.method || "GET", headers: {} };
    if (opts.raw !== undefined) { init.body = opts.raw; }
    else if (opts.body !== undefined) {
      init.body = JSON.stringify(opts.body);
      init.headers["Content-Type"] = "application/json";
    }
    const r = await fetch(API + path, init);
    let data = null;
    try { data = await r.json(); } catch (e) { data = null; }
    if (!r.ok) {
      let msg = "The tool answered with error " + r.status + ".";
      if (data && data.detail) {
        msg = typeof data.detail === "string" ? data.detail
          : data.detail.map((d) => (d.loc || []).slice(1).join(".") + ": " + d.msg).join("; ");
      }
      throw new Error(msg);
    }
    return data;
  }

  async function send(path, body, method = "POST") {
    try {
      const s = await api(path, { method, body });
      showError("");
      render(s);
      return s;
    } catch (e) {
      showError(e.message);
      return null;
    }
  }
  window.drovisioDesigner = { send, api, state: () => state };

  function setVal(el, v) {
    if (document.activeElement === el) return;
    if (el.type === "checkbox") el.checked = !!v; else el.value = (v === null || v === undefined) ? "" : v;
  }

  function fillSelect(el, items, value) {
    const key = JSON.stringify(items);
    if (el.dataset.items !== key) {
      el.innerHTML = "";
      for (const it of items) {
        const o = document.createElement("option");
        o.value = it.id; o.textContent = it.label; el.appendChild(o);
      }
      el.dataset.items = key;
    }
    if (value !== undefined) setVal(el, value);
  }

  function el(tag, attrs = {}, text) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    return e;
  }

  function render(s) {
    if (!s || s.version === undefined) return;
    state = s;
    version = s.version;
    $("#status").textContent = s.message || "";
    for (const b of $$(".mode-btn")) b.setAttribute("aria-pressed", String(b.dataset.mode === s.mode));
    $("#undo").disabled = !s.can_undo;
    $("#redo").disabled = !s.can_redo;
    fillSelect($("#example"), s.examples);
    fillSelect($("#family"), s.families, s.ids ? s.ids.family : undefined);
    fillSelect($("#dot-color"), s.palette.map((p) => ({ id: p.name, label: p.name })), s.defaults.dot_color);
    setVal($("#code-size"), s.defaults.code_size_mm);
    setVal($("#dot-diameter"), s.defaults.dot_diameter_mm);
    setVal($("#grid"), s.defaults.grid_mm);
    $("#snap-mm").textContent = s.defaults.snap_mm;
    $("#layouts-dir").textContent = s.layouts_dir;
    $("#camera-name").textContent = s.camera;

    const m = s.mesh;
    const info = $("#mesh-info");
    if (!m) {
      info.textContent = "No model loaded yet.";
      $("#units-row").hidden = true;
    } else {
      info.textContent = `Model: ${m.name} — ${m.size_mm.map((v) => Math.round(v)).join(" × ")} mm `
        + `(along the brick axes), ${m.triangles} triangles, ${m.flat_faces} flat faces.`
        + (m.units_guessed ? " Units guessed from the size: check them below." : "");
      $("#units-row").hidden = false;
      setVal($("#units"), m.units);
    }

    // markers
    const list = $("#marker-list");
    list.innerHTML = "";
    for (const mk of s.markers) {
      const li = el("li", { "data-index": mk.index, "data-kind": mk.kind });
      if (s.selected === mk.index) li.className = "selected";
      const icon = mk.kind === "aruco" ? el("span", { class: "codeicon", "aria-hidden": "true" })
        : el("span", { class: "swatch", "aria-hidden": "true", style: `background: rgb(${mk.rgb.join(",")})` });
      const desc = mk.kind === "aruco" ? `${mk.label} (id ${mk.id}), ${mk.size_mm} mm`
        : `${mk.label}, ${mk.size_mm} mm`;
      const b = el("button", { type: "button", "aria-pressed": String(s.selected === mk.index) },
        `${desc} at (${mk.center_mm.map((v) => Math.round(v)).join(", ")}) mm`);
      b.addEventListener("click", () => send("/select", { index: mk.index }));
      li.append(icon, b);
      list.appendChild(li);
    }
    const nCodes = s.markers.filter((x) => x.kind === "aruco").length;
    $("#marker-count").textContent = s.markers.length
      ? `${nCodes} code(s), ${s.markers.length - nCodes} dot(s).`
      : (m ? "No markers yet: press 'Add codes' or 'Add dots', then click on the model." : "No markers yet.");

    const ed = $("#marker-editor");
    const sel = s.selected !== null && s.selected !== undefined ? s.markers[s.selected] : null;
    ed.hidden = !sel;
    if (sel) {
      $("#editor-title").textContent = "Selected: " + sel.label;
      setVal($("#m-size"), sel.size_mm);
      $("#m-color-box").hidden = sel.kind !== "dot";
      $("#m-slot-box").hidden = sel.kind !== "aruco";
      fillSelect($("#m-color"), s.palette.map((p) => ({ id: p.name, label: p.name })), sel.color);
      if (sel.kind === "aruco") setVal($("#m-slot"), sel.slot);
      for (const b of $$("[data-rotate]")) b.disabled = sel.kind !== "aruco";
    }

    // checks
    const checks = $("#checks");
    checks.innerHTML = "";
    for (const c of s.checks) {
      const li = el("li", { class: c.severity, "data-key": c.key });
      li.append(el("span", { class: "sev" }, c.severity === "info" ? "note" : c.severity), document.createTextNode(c.message));
      if (c.fixes.length) {
        const box = el("div", { class: "fixes" });
        for (const f of c.fixes) {
          const b = el("button", { type: "button", class: "fix" }, f.label);
          b.addEventListener("click", () => send("/fix", { action: f.action }));
          box.appendChild(b);
        }
        li.appendChild(box);
      }
      checks.appendChild(li);
    }

    // ids
    if (s.ids) {
      setVal($("#first-id"), s.ids.first_id);
      setVal($("#first-id-auto"), s.ids.first_id_auto);
      $("#first-id").disabled = s.ids.first_id_auto;
      setVal($("#ipi"), s.ids.ids_per_instance);
      setVal($("#ipi-auto"), s.ids.ipi_auto);
      $("#ipi").disabled = s.ids.ipi_auto;
      setVal($("#instances"), s.ids.instances);
      $("#ids-info").textContent = s.ids.block
        ? `Brick k carries ids ${s.ids.first_id} + k × ${s.ids.ids_per_instance} + slot: ids ${s.ids.block[0]} to ${s.ids.block[1]} in ${s.ids.dictionary || "(no dictionary large enough)"}.`
        : "No codes yet, so no ids.";
    }
    if (s.layout) {
      setVal($("#symmetry"), s.layout.symmetry);
      setVal($("#layout-name"), s.layout.name);
      setVal($("#layout-description"), s.layout.description);
    }

    // exports
    const links = { "#dl-pdf": "/export/sheet.pdf", "#dl-svg": "/export/sheet.svg?page=1",
      "#dl-json": "/export/layout.json", "#dl-glb": "/export/brick.glb", "#dl-stl": "/export/mesh.stl" };
    for (const [id, path] of Object.entries(links)) {
      const a = $(id);
      const ok = s.can_export || (id === "#dl-stl" && !!m);
      if (ok) { a.href = API + path + (path.includes("?") ? "&" : "?") + "v=" + s.version; a.removeAttribute("aria-disabled"); }
      else { a.removeAttribute("href"); a.setAttribute("aria-disabled", "true"); }
    }
    $("#save-button").disabled = !s.can_export;
    $("#verify-button").disabled = !s.can_export;
  }

  // ---- events
  for (const b of $$(".mode-btn")) b.addEventListener("click", () => send("/mode", { mode: b.dataset.mode }));
  $("#undo").addEventListener("click", () => send("/undo"));
  $("#redo").addEventListener("click", () => send("/redo"));
  for (const b of $$("[data-frame]")) b.addEventListener("click", () => send("/frame", { action: b.dataset.frame, angle_deg: 90 }));
  $("#open-example").addEventListener("click", () => send("/open", { example: $("#example").value }));
  $("#units").addEventListener("change", (e) => send("/units", { units: e.target.value }));

  $("#upload-input").addEventListener("change", async (e) => {
    const f = e.target.files[0];
    if (!f) return;
    const limit = state ? state.max_upload_mb : 50;
    if (f.size > limit * 1024 * 1024) {
      showError(`This file is ${Math.round(f.size / 1048576)} MB; the limit is ${limit} MB. Simplify the model in your CAD program (fewer triangles) and upload it again.`);
      e.target.value = "";
      return;
    }
    $("#status").textContent = `Uploading ${f.name}…`;
    try {
      const s = await api(`/mesh?filename=${encodeURIComponent(f.name)}&units=auto`, { method: "POST", raw: f });
      showError("");
      render(s);
    } catch (err) {
      showError(err.message);
      $("#status").textContent = "";
    }
    e.target.value = "";
  });

  const num = (id) => { const v = $(id).value; return v === "" ? null : Number(v); };
  $("#code-size").addEventListener("change", () => send("/defaults", { code_size_mm: num("#code-size") }));
  $("#dot-diameter").addEventListener("change", () => send("/defaults", { dot_diameter_mm: num("#dot-diameter") }));
  $("#dot-color").addEventListener("change", (e) => send("/defaults", { dot_color: e.target.value }));
  $("#grid").addEventListener("change", () => send("/defaults", { grid_mm: num("#grid") }));
  $("#family").addEventListener("change", (e) => send("/layout", { family: e.target.value }));

  const selIndex = () => (state ? state.selected : null);
  $("#m-size").addEventListener("change", () => send(`/markers/${selIndex()}`, { size_mm: num("#m-size") }));
  $("#m-color").addEventListener("change", (e) => send(`/markers/${selIndex()}`, { color: e.target.value }));
  $("#m-slot").addEventListener("change", () => send(`/markers/${selIndex()}`, { slot: num("#m-slot") }));
  for (const b of $$("[data-rotate]")) b.addEventListener("click", () => send(`/markers/${selIndex()}`, { rotate_deg: Number(b.dataset.rotate) }));
  for (const b of $$("[data-nudge]")) b.addEventListener("click", () => {
    const step = state && state.defaults.grid_mm > 0 ? state.defaults.grid_mm : 1;
    const [r, u] = b.dataset.nudge.split(",").map(Number);
    send(`/markers/${selIndex()}`, { nudge_mm: [r * step, u * step] });
  });
  $("#m-centre").addEventListener("click", () => send(`/markers/${selIndex()}`, { centre: true }));
  $("#m-delete").addEventListener("click", () => send(`/markers/${selIndex()}`, undefined, "DELETE"));

  $("#first-id-auto").addEventListener("change", (e) => send("/layout", { first_id: e.target.checked ? null : (num("#first-id") ?? 0) }));
  $("#first-id").addEventListener("change", () => send("/layout", { first_id: num("#first-id") }));
  $("#ipi-auto").addEventListener("change", (e) => send("/layout", { ids_per_instance: e.target.checked ? null : (num("#ipi") ?? 1) }));
  $("#ipi").addEventListener("change", () => send("/layout", { ids_per_instance: num("#ipi") }));
  $("#instances").addEventListener("change", () => send("/layout", { instances: num("#instances") }));
  $("#symmetry").addEventListener("change", (e) => send("/layout", { symmetry: e.target.value }));
  $("#layout-name").addEventListener("change", (e) => send("/layout", { name: e.target.value }));
  $("#layout-description").addEventListener("change", (e) => send("/layout", { description: e.target.value }));
  $("#save-button").addEventListener("click", async () => {
    const s = await send("/save", { overwrite: $("#overwrite").checked });
    if (s && s.saved) $("#status").textContent = s.message;
  });
  $("#verify-button").addEventListener("click", async () => {
    const b = $("#verify-button");
    b.disabled = true;
    $("#status").textContent = "Simulating a drone photo and looking for the brick…";
    try {
      const v = await api("/verify", { method: "POST" });
      showError("");
      const list = $("#verify-list");
      list.innerHTML = "";
      for (const r of v.results) {
        const what = r.method === "aruco" ? "Codes" : "Dots";
        list.appendChild(el("li", { "data-method": r.method }, r.found
          ? `${what}: brick found from ${r.distance_m} m, position off by ${r.position_error_mm} mm, turn (yaw) off by ${Math.abs(r.yaw_error_deg).toFixed(2)}°, tilt and turn together ${r.angle_error_deg.toFixed(2)}°.`
          : `${what}: the brick was NOT found from ${r.distance_m} m. Make the markers bigger or change their layout.`));
      }
      $("#verify-image").src = v.image;
      $("#verify-result").hidden = false;
      $("#status").textContent = "Simulated photo checked.";
    } catch (e) {
      showError(e.message);
    }
    b.disabled = !(state && state.can_export);
  });
  for (const a of $$("a.dl")) a.addEventListener("click", (e) => { if (a.getAttribute("aria-disabled") === "true") e.preventDefault(); });

  // ---- start: state, 3D view, then follow changes made in the 3D view (long poll)
  async function startViewer() {
    try {
      const v = await api("/viewer");
      $("#viewer").src = v.url;
      $("#viewer-status").textContent = "3D view: drag to turn, scroll to zoom.";
      $("#viewer").dataset.port = v.port;
    } catch (e) {
      $("#viewer-status").textContent = "The 3D view could not start: " + e.message;
    }
  }
  async function follow() {
    for (;;) {
      try {
        render(await api("/state?after=" + version));
      } catch (e) {
        await new Promise((r) => setTimeout(r, 2000));
      }
    }
  }
  api("/state").then((s) => { render(s); startViewer(); follow(); }).catch((e) => showError(e.message));
})();
