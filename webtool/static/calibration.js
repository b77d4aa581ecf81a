// Calibration page: polls /api/calibration/state, streams /api/calibration/frame.jpg, and draws
// the coverage heatmap and the next-pose hint over the picture. The server keeps everything
// (views are saved as they are taken), so a reload simply picks up where it was.
"use strict";
(() => {
  const API = "/api/calibration";
  const $ = (id) => document.getElementById(id);
  const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
  const SVGNS = "http://www.w3.org/2000/svg";

  let last = null;          // last state
  let viewsSig = "";        // views strip signature
  let heatSig = "";
  let resultShown = null;   // result_seq rendered
  let sessionId = null;
  let frameSeq = -1;
  let frameUrl = null;
  let lastViewCount = null;

  function setText(id, text) {
    const el = $(id);
    if (el && el.textContent !== text) el.textContent = text;
  }
  function status(id, text, isError) {
    const el = $(id);
    el.textContent = text || "";
    el.classList.toggle("error", !!isError);
  }
  async function call(method, path, body) {
    const opts = { method, cache: "no-store", headers: {} };
    if (body instanceof FormData) opts.body = body;
    else if (body !== undefined) {
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
    const r = await fetch(API + path, opts);
    let data = null;
    try { data = await r.json(); } catch (e) { data = null; }
    if (!r.ok) {
      const msg = data && data.detail ? (typeof data.detail === "string" ? data.detail
        : JSON.stringify(data.detail)) : `The server answered ${r.status}.`;
      throw new Error(msg);
    }
    return data;
  }
  const fmt = (x, d = 2) => (x === null || x === undefined ? "—" : Number(x).toFixed(d));

  // ------------------------------------------------------------------------ live picture
  async function frameLoop() {
    const img = $("live");
    const stage = $("stage");
    for (;;) {
      try {
        const r = await fetch(`${API}/frame.jpg?after=${frameSeq}`, { cache: "no-store" });
        if (r.ok) {
          frameSeq = Number(r.headers.get("X-Frame-Seq") || frameSeq);
          const url = URL.createObjectURL(await r.blob());
          img.src = url;
          if (frameUrl) URL.revokeObjectURL(frameUrl);
          frameUrl = url;
          stage.classList.remove("stale");
          await sleep(document.hidden ? 1500 : 80);
        } else {
          stage.classList.add("stale");
          await sleep(1000);
        }
      } catch (e) {
        stage.classList.add("stale");
        await sleep(2000);
      }
    }
  }

  // ------------------------------------------------------------------------ state
  async function poll() {
    for (;;) {
      try {
        const s = await call("GET", "/state");
        $("conn").hidden = true;
        render(s);
      } catch (e) {
        $("conn").hidden = false;
      }
      await sleep(document.hidden ? 3000 : 700);
    }
  }

  function render(s) {
    if (sessionId !== null && s.session.id !== sessionId) {
      viewsSig = heatSig = ""; resultShown = null; lastViewCount = null;
    }
    sessionId = s.session.id;
    last = s;
    renderCamera(s);
    renderOverlay(s);
    renderProgress(s);
    renderViews(s);
    renderResult(s);
    const prints = s.session.print_square_mm || {};
    const printed = Object.entries(prints).filter(([, mm]) => mm !== s.session.square_mm)
      .map(([paper, mm]) => `${mm} mm on ${paper}`);
    setText("s-board", `${s.session.cols} × ${s.session.rows} inner corners, squares of ` +
      `${s.session.square_mm} mm` + (s.session.square_measured ? " (measured)" : "") +
      (printed.length ? ` — printed smaller to fit: ${printed.join(", ")}; measure your print` : "") +
      ` (${s.session.board})`);
    for (const [paper, mm] of Object.entries(prints)) {
      const a = $("print-" + paper.toLowerCase());
      if (a) a.textContent = `${paper} (${mm} mm squares)`;
    }
    setText("s-source", s.session.source);
    setText("s-folder", s.session.folder);
    setText("s-camera", s.in_use.camera_file || "none");
  }

  function renderCamera(s) {
    const c = s.camera;
    const banner = $("camera-status");
    let text;
    banner.classList.remove("warn", "idle");
    if (c.state === "ok") text = `Camera connected: ${s.session.source}.`;
    else if (c.state === "disconnected") { text = c.message; banner.classList.add("warn"); }
    else if (c.state === "starting") { text = "Starting the camera…"; banner.classList.add("idle"); }
    else { text = c.message || "Camera paused."; banner.classList.add("idle"); }
    setText("camera-status", text);
    const msg = $("stage-msg");
    if (c.state === "ok") msg.hidden = true;
    else {
      msg.hidden = false;
      setText("stage-msg", c.state === "disconnected" ? "Camera disconnected — retrying…"
        : "Waiting for the camera…");
    }
    setText("next-action", s.progress.next);
    const fb = $("feedback");
    setText("feedback", c.state === "ok" ? s.feedback.message : "");
    fb.classList.toggle("kept", !!s.feedback.kept);
    const auto = $("auto");
    auto.setAttribute("aria-pressed", s.auto_capture ? "true" : "false");
    setText("auto", s.auto_capture ? "Auto-capture: on" : "Auto-capture: off");
    $("capture").disabled = c.state !== "ok";
    const n = s.views.length;
    if (lastViewCount !== null && n > lastViewCount) {
      const st = $("stage");
      st.classList.add("flash");
      setTimeout(() => st.classList.remove("flash"), 600);
    }
    lastViewCount = n;
  }

  function renderOverlay(s) {
    const [w, h] = s.camera.image_size;
    const svg = $("overlay");
    const vb = `0 0 ${w} ${h}`;
    if (svg.getAttribute("viewBox") !== vb) {
      svg.setAttribute("viewBox", vb);
      $("stage").style.aspectRatio = `${w} / ${h}`;
    }
    const cov = s.coverage;
    const sig = JSON.stringify([w, h, cov.covered]);
    if (sig !== heatSig) {
      heatSig = sig;
      const g = $("heatmap");
      g.replaceChildren();
      const cw = w / cov.cols, ch = h / cov.rows;
      cov.covered.forEach((row, j) => row.forEach((v, i) => {
        const r = document.createElementNS(SVGNS, "rect");
        r.setAttribute("x", (i * cw).toFixed(1));
        r.setAttribute("y", (j * ch).toFixed(1));
        r.setAttribute("width", cw.toFixed(1));
        r.setAttribute("height", ch.toFixed(1));
        const hue = Math.round(120 * Math.min(1, v));
        r.setAttribute("fill", `hsl(${hue}, 80%, 45%)`);
        r.setAttribute("fill-opacity", "0.30");
        r.setAttribute("stroke", "rgba(255,255,255,0.35)");
        r.setAttribute("stroke-width", "1");
        g.appendChild(r);
      }));
      g.setAttribute("data-views", String(s.views.length));
    }
    const sug = s.suggestion || {};
    const pts = (sug.outline_px || []).map((p) => `${p[0]},${p[1]}`).join(" ");
    const poly = $("hint-outline");
    const showHint = !(s.progress.ok) && pts;
    poly.setAttribute("points", showHint ? pts : "");
  }

  function mark(id, ok) { $(id).classList.toggle("ok", !!ok); }

  function renderProgress(s) {
    const p = s.progress;
    let li = $("p-views");
    li.querySelector(".val").textContent = String(p.views);
    li.querySelector(".goal").textContent = p.views >= p.views_needed
      ? `at least ${p.views_needed} needed: done; more, varied views make it better`
      : `at least ${p.views_needed} needed for a verdict`;
    const m1 = li.querySelector("meter"); m1.max = p.views_needed; m1.value = Math.min(p.views, p.views_needed);
    mark("p-views", p.views >= p.views_needed);

    li = $("p-cover");
    li.querySelector(".val").textContent = `${Math.round(100 * p.covered_fraction)} %`;
    const unc = s.coverage.uncovered_regions || [];
    li.querySelector(".goal").textContent = unc.length
      ? `not covered yet: ${unc.join(", ")}` : "every part of the picture has been covered";
    li.querySelector("meter").value = p.covered_fraction;
    mark("p-cover", unc.length === 0);

    li = $("p-uncert");
    li.querySelector(".val").textContent = p.p95_px === null ? "—" : `${fmt(p.p95_px)} px`;
    li.querySelector(".goal").textContent = p.p95_px === null
      ? `known after ${p.solve_needs} views; must be ${p.p95_limit_px} px or less`
      : `must be ${p.p95_limit_px} px or less`;
    const m3 = li.querySelector("meter");
    m3.value = p.p95_px === null ? 0 : Math.min(1, p.p95_limit_px / Math.max(p.p95_px, 1e-9));
    mark("p-uncert", p.p95_px !== null && p.p95_px <= p.p95_limit_px);

    const ul = $("reasons");
    const sig = JSON.stringify(p.reasons);
    if (ul.dataset.sig !== sig) {
      ul.dataset.sig = sig;
      ul.replaceChildren(...(p.views ? p.reasons : []).map((r) => {
        const e = document.createElement("li"); e.textContent = r; return e;
      }));
    }
    const lens = $("lens");
    if (s.lens && document.activeElement !== lens && lens.value !== s.lens.model) {
      lens.value = s.lens.model;
    }
    const solve = $("solve");
    const sv = s.solve;
    const enough = p.views >= p.solve_needs;
    solve.disabled = !enough;
    solve.classList.toggle("go", p.ok && !sv.show_result);
    setText("solve", sv.solving && sv.show_result ? "Solving…" : "Solve");
    const st = $("solve-status");
    if (!enough) status("solve-status", `Solve needs at least ${p.solve_needs} views.`);
    else if (sv.error) status("solve-status", `The solve failed: ${sv.error}`, true);
    else if (sv.solving && sv.show_result) status("solve-status", "Solving in the background — you can keep capturing.");
    else if (st.dataset.sticky !== "1") status("solve-status", p.ok ? "Good enough: press Solve." : "");
  }

  function renderViews(s) {
    setText("views-count", String(s.views.length));
    const sig = JSON.stringify(s.views.map((v) => [v.id, v.rms_px, v.note]));
    if (sig === viewsSig) return;
    viewsSig = sig;
    const ol = $("views");
    if (!s.views.length) {
      const e = document.createElement("li");
      e.className = "empty";
      e.textContent = "No views yet.";
      ol.replaceChildren(e);
      return;
    }
    const items = s.views.slice().reverse().map((v) => {
      const li = document.createElement("li");
      li.dataset.viewId = String(v.id);
      if (v.note) li.classList.add("outlier");
      const img = document.createElement("img");
      img.src = v.thumb; img.alt = `View ${v.id}`; img.loading = "lazy";
      img.width = 200; img.height = 150;
      const label = document.createElement("p");
      label.className = "label";
      const err = v.rms_px === null ? "error: after the solve" : `error ${fmt(v.rms_px, 2)} px`;
      label.textContent = `#${v.id} · ${v.origin === "upload" ? "photo" : "camera"} · ${err}`;
      li.append(img, label);
      if (v.note) {
        const n = document.createElement("p"); n.className = "label"; n.textContent = `Not used: ${v.note}`;
        li.append(n);
      }
      const del = document.createElement("button");
      del.type = "button";
      del.textContent = "Delete";
      del.setAttribute("aria-label", `Delete view ${v.id}`);
      del.addEventListener("click", () => onDelete(del, v.id));
      li.append(del);
      return li;
    });
    ol.replaceChildren(...items);
  }

  async function onDelete(btn, id) {
    if (!btn.classList.contains("armed")) {
      btn.classList.add("armed");
      btn.textContent = "Tap again to delete";
      setTimeout(() => { btn.classList.remove("armed"); btn.textContent = "Delete"; }, 3000);
      return;
    }
    btn.disabled = true;
    try { await call("DELETE", `/views/${id}`); viewsSig = ""; }
    catch (e) { status("capture-status", e.message, true); btn.disabled = false; }
  }

  // ------------------------------------------------------------------------ result
  const BASE_PARAMS = [["fx", "focal length x", "px"], ["fy", "focal length y", "px"],
    ["cx", "image centre x", "px"], ["cy", "image centre y", "px"]];
  // distortion coefficients of each lens model, in the camera file's order
  const DIST_NAMES = {
    plumb_bob: ["k1", "k2", "p1", "p2", "k3"],
    rational_polynomial: ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"],
    thin_prism: ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4"],
    tilted: ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty"],
    fisheye: ["k1", "k2", "k3", "k4"],
  };
  const DIST_KIND = { p: "tangential", s: "thin prism", t: "sensor tilt" };
  const distLabel = (k) => `${DIST_KIND[k[0]] || "radial"} ${k}`;
  const LENS_NAMES = { plumb_bob: "normal lens (5 coefficients)",
    rational_polynomial: "wide lens (rational, 8 coefficients)",
    thin_prism: "wide lens with thin prism (12 coefficients)",
    tilted: "wide lens, thin prism and tilted sensor (14 coefficients)",
    fisheye: "fisheye (Kannala–Brandt, 4 coefficients)" };
  // OpenCV's model with 12 or 14 coefficients is written as rational_polynomial
  const lensKey = (cam) => {
    const m = cam.model || "plumb_bob";
    if (m !== "rational_polynomial") return m;
    const n = (cam.dist || []).length;
    return n >= 14 ? "tilted" : n >= 12 ? "thin_prism" : m;
  };

  async function renderResult(s) {
    const sec = $("result");
    const sv = s.solve;
    if (!(sv.show_result && sv.has_result)) { sec.hidden = true; return; }
    $("result-stale").hidden = sv.current;
    if (resultShown === sv.result_seq) return;
    resultShown = sv.result_seq;
    let rep;
    try { rep = await call("GET", "/result"); } catch (e) { resultShown = null; return; }
    sec.hidden = false;
    const v = rep.verdict || {};
    const box = $("result-verdict");
    box.className = "verdict " + (v.ok ? "ok" : "bad");
    const h = document.createElement("h3");
    h.textContent = v.ok ? "Good calibration" : "Not good enough yet";
    const parts = [h];
    const addList = (items, title) => {
      if (!items || !items.length) return;
      if (title) { const p = document.createElement("p"); p.textContent = title; parts.push(p); }
      const ul = document.createElement("ul");
      items.forEach((t) => { const li = document.createElement("li"); li.textContent = t; ul.append(li); });
      parts.push(ul);
    };
    if (v.ok) {
      const p = document.createElement("p");
      p.textContent = "The uncertainty is small over the whole picture. Download the camera file or use it on this server.";
      parts.push(p);
    }
    addList(v.reasons, v.ok ? "" : "Why:");
    box.replaceChildren(...parts);
    // the solver's notes (fixed coefficients, model choice, rejected views) are figures for
    // experts: one click away, under "Details"
    const notes = [];
    if (v.advice && v.advice.length) {
      const p = document.createElement("p"); p.textContent = "Notes of the solver:";
      const ul = document.createElement("ul");
      v.advice.forEach((t) => { const li = document.createElement("li"); li.textContent = t; ul.append(li); });
      notes.push(p, ul);
    }
    $("result-notes").replaceChildren(...notes);

    const cam = rep.camera;
    const model = lensKey(cam);
    const names = DIST_NAMES[model] || DIST_NAMES.plumb_bob;
    const PARAMS = BASE_PARAMS.concat(names.map((k) => [k, distLabel(k), ""]));
    const vals = { fx: cam.fx, fy: cam.fy, cx: cam.cx, cy: cam.cy };
    names.forEach((k, i) => { vals[k] = cam.dist[i]; });
    const choice = rep.model_choice;
    setText("lens-result", `Lens model: ${LENS_NAMES[model] || model}.`
      + (choice ? ` ${choice.reason}.` : ""));
    const std = rep.std || {};
    const fixed = rep.fixed || {};
    const rows = PARAMS.map(([k, label, unit]) => {
      const tr = document.createElement("tr");
      const isPx = unit === "px";
      const td = (t, cls) => { const c = document.createElement("td"); c.textContent = t; if (cls) c.className = cls; return c; };
      const th = document.createElement("th"); th.scope = "row"; th.textContent = `${k} (${label})`;
      const val = vals[k] === undefined ? "—" : (isPx ? `${fmt(vals[k], 2)} px` : Number(vals[k]).toPrecision(5));
      const sd = fixed[k] ? "fixed" : (std[k] === undefined || std[k] === null ? "—"
        : (isPx ? `± ${fmt(std[k], 2)} px` : `± ${Number(std[k]).toPrecision(2)}`));
      tr.append(th, td(val, "num"), td(sd, "num"));
      tr.id = `param-${k}`;
      return tr;
    });
    $("params").querySelector("tbody").replaceChildren(...rows);
    const flat = rep.board_flatness;
    const flatEl = $("board-flatness");
    flatEl.textContent = flat && flat.computed ? `Board: ${flat.summary}.` : "";
    flatEl.classList.toggle("error", Boolean(flat && flat.computed && flat.matters));
    setText("rms", `RMS reprojection error: ${fmt(rep.rms_px, 3)} px over ${rep.views_kept} views.`);
    setText("rms-def", `RMS: ${rep.rms_definition || ""}. A small RMS alone does not make a good calibration: the uncertainty below does.`);
    const u = rep.uncertainty_px || {};
    setText("uncertainty-stats", `Uncertainty: half the picture within ${fmt(u.p50)} px, 95 % within ${fmt(u.p95)} px, worst ${fmt(u.max)} px (limit for a good calibration: ${s.progress.p95_limit_px} px at 95 %).`);
    const cv = rep.cross_validation_px || {};
    setText("crossval", cv.p95 !== null && cv.p95 !== undefined
      ? `Cross-check (two halves of the views solved apart): they differ by ${fmt(cv.p95)} px at 95 % of the picture.`
      : (cv.skipped ? `Cross-check skipped: ${cv.skipped}.` : ""));
    $("uncertainty-map").src = `${API}/uncertainty.png?r=${sv.result_seq}&s=${s.session.id}`;
    const inUse = s.in_use.this_session;
    if (inUse) status("use-status", `In use: ${s.in_use.camera_file}`);
  }

  // ------------------------------------------------------------------------ actions
  $("auto").addEventListener("click", async () => {
    const on = !(last && last.auto_capture);
    try { await call("POST", "/auto", { on }); setText("auto", on ? "Auto-capture: on" : "Auto-capture: off"); $("auto").setAttribute("aria-pressed", String(on)); }
    catch (e) { status("capture-status", e.message, true); }
  });
  $("capture").addEventListener("click", async () => {
    status("capture-status", "Capturing…");
    try { const r = await call("POST", "/capture"); status("capture-status", r.message); }
    catch (e) { status("capture-status", e.message, true); }
  });
  $("lens").addEventListener("change", async (ev) => {
    status("lens-status", "Solving again with this lens model…");
    try { await call("POST", "/lens", { model: ev.target.value }); status("lens-status", ""); }
    catch (e) { status("lens-status", e.message, true); }
  });
  async function solveNow() {
    const st = $("solve-status");
    st.dataset.sticky = "1";
    status("solve-status", "Solving in the background — you can keep capturing.");
    try {
      await call("POST", "/solve");
      if (last) { last.solve.show_result = true; }
    } catch (e) { status("solve-status", e.message, true); }
    setTimeout(() => { st.dataset.sticky = ""; }, 4000);
  }
  // Printers scale pages: before the first solve of a camera's session, ask for the square
  // size as measured on the print (the views stay whatever it is).
  $("solve").addEventListener("click", () => {
    if (last && !last.session.square_measured) {
      $("square-mm").value = last.session.square_mm;
      $("square-form").hidden = false;
      $("square-mm").focus();
      status("solve-status", "First the square size, as measured on your print.");
      return;
    }
    solveNow();
  });
  $("square-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try {
      const r = await call("POST", "/square", { square_m: Number($("square-mm").value) / 1000 });
      if (last) { last.session.square_measured = true; last.session.square_mm = r.square_mm; }
      $("square-form").hidden = true;
      await solveNow();
    } catch (e) { status("solve-status", e.message, true); }
  });
  $("use").addEventListener("click", async () => {
    status("use-status", "Saving…");
    try { const r = await call("POST", "/use"); status("use-status", r.message); }
    catch (e) { status("use-status", e.message, true); }
  });
  $("show-heatmap").addEventListener("change", (e) => $("stage").classList.toggle("hide-heatmap", !e.target.checked));
  $("show-hint").addEventListener("change", (e) => $("stage").classList.toggle("hide-hint", !e.target.checked));

  async function upload(input) {
    const files = Array.from(input.files || []);
    input.value = "";
    if (!files.length) return;
    const list = $("upload-results");
    list.replaceChildren();
    status("upload-summary", `Sending and checking ${files.length} file${files.length > 1 ? "s" : ""}…`);
    const fd = new FormData();
    files.forEach((f) => fd.append("files", f, f.webkitRelativePath || f.name));
    try {
      const r = await call("POST", "/upload", fd);
      status("upload-summary", r.summary + ".", r.kept === 0);
      list.replaceChildren(...r.files.map((f) => {
        const li = document.createElement("li");
        li.className = f.ok ? "ok" : "bad";
        li.textContent = `${f.file}: ${f.message}`;
        return li;
      }));
    } catch (e) {
      status("upload-summary", `The upload failed: ${e.message} Nothing already kept is lost; try again.`, true);
    }
  }
  $("upload-files").addEventListener("change", (e) => upload(e.target));
  $("upload-folder").addEventListener("change", (e) => upload(e.target));

  let nsArmed = false;
  $("new-session-form").addEventListener("submit", async (e) => {
    e.preventDefault();
    const btn = $("ns-start");
    if (!nsArmed) {
      nsArmed = true;
      btn.textContent = "Tap again to start a new session";
      setTimeout(() => { nsArmed = false; btn.textContent = "Start a new session"; }, 4000);
      return;
    }
    nsArmed = false;
    btn.textContent = "Start a new session";
    const board = `chessboard:${$("ns-cols").value}x${$("ns-rows").value}`;
    const square_m = Number($("ns-square").value) / 1000;
    try {
      const r = await call("POST", "/session", { board, square_m });
      status("ns-status", `New session ${r.session} started (${r.board}).`);
      $("new-session").open = false;
    } catch (err) { status("ns-status", err.message, true); }
  });

  // defaults of the new-session form: the current board
  (async () => {
    poll();
    frameLoop();
    for (let i = 0; i < 50 && !last; i++) await sleep(100);
    if (last) {
      $("ns-cols").value = last.session.cols;
      $("ns-rows").value = last.session.rows;
      $("ns-square").value = last.session.square_mm;
    }
  })();
})();
