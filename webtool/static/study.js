(function () {
  "use strict";
  const $ = (id) => document.getElementById(id);
  let timer = null;

  async function call(method, url) {
    const r = await fetch(url, {method});
    let js = null;
    try { js = await r.json(); } catch (e) { js = {detail: r.status + " " + r.statusText}; }
    if (!r.ok) throw new Error(js.detail || (r.status + " " + r.statusText));
    return js;
  }

  function cell(tr, text) { const td = document.createElement("td"); td.textContent = text; tr.appendChild(td); return td; }

  async function list() {
    const js = await call("GET", "/api/study/reports");
    $("study-folder").textContent = js.folder;
    const body = $("study-reports");
    body.innerHTML = "";
    for (const s of js.skipped || []) {   // a folder that is not a readable report: named
      const tr = document.createElement("tr");
      tr.dataset.skipped = s.name;
      cell(tr, s.name); cell(tr, "skipped: " + s.error).colSpan = 4;
      body.appendChild(tr);
    }
    if (!js.reports.length && !(js.skipped || []).length) { body.innerHTML = '<tr><td colspan="5">No report yet: start the sample study above, or run drovisio study run.</td></tr>'; return; }
    for (const r of js.reports) {
      const tr = document.createElement("tr");
      tr.dataset.report = r.name;
      const a = document.createElement("a");
      a.href = "/study/reports/" + encodeURIComponent(r.name) + "/report.html";
      a.target = "_blank"; a.rel = "noopener"; a.textContent = r.name;
      cell(tr, "").appendChild(a);
      cell(tr, r.protocol || "–"); cell(tr, String(r.frames ?? "–"));
      cell(tr, r.seconds != null ? Math.round(r.seconds) + " s" : "–"); cell(tr, String(r.skipped));
      body.appendChild(tr);
    }
  }

  function show(p) {
    const bar = $("study-progress");
    bar.hidden = !p.running && !p.report;
    bar.value = p.fraction || 0;
    $("study-start").disabled = !!p.running;
    const msg = $("study-msg");
    msg.className = "msg" + (p.error ? " error" : "");
    msg.textContent = p.error ? "The study stopped: " + p.error
      : p.running ? Math.round(100 * (p.fraction || 0)) + " % — " + (p.message || "")
      : p.report ? "Done: report " + p.report + " (below)."
      : p.cancelled ? "The study was cancelled before its end: no report." : "";
  }

  async function poll() {
    try {
      const p = await call("GET", "/api/study/progress");
      show(p);
      if (p.running) { timer = setTimeout(poll, 700); return; }
      await list();
    } catch (e) { $("study-msg").className = "msg error"; $("study-msg").textContent = e.message; }
  }

  $("study-start").addEventListener("click", async () => {
    try { show(await call("POST", "/api/study/start")); clearTimeout(timer); poll(); }
    catch (e) { $("study-msg").className = "msg error"; $("study-msg").textContent = e.message; }
  });
  list().catch((e) => { $("study-msg").textContent = e.message; });
  poll();
})();
