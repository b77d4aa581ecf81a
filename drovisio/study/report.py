"""The study's report: one self-contained HTML file (figures embedded), the per-frame results
as JSON Lines and the summary as JSON, with the protocol, the versions, the machine and the
command that reproduces it."""

from __future__ import annotations

import base64
import html
import json
import os
import platform
import sys
from importlib.metadata import version
from pathlib import Path

import cv2
import numpy as np

from drovisio.fileio import atomic_write_bytes, atomic_write_text
from drovisio.study.analysis import summarise
from drovisio.study.figures import box_figure, fps_figure, memory_figure
from drovisio.study.methods import METHODS
from drovisio.study.run import figure_ids

__all__ = ["THESIS", "write_report"]

#: the thesis's own figures (DESIGN.md), beside ours in the report
THESIS = {
    "6.2": "dots, x/y at 1.9 m: < 4 cm, growing away from the image centre",
    "6.3": "dots, z: ~7 %, always < 10 %, < 5 cm under 1 m",
    "6.4": "dots, rotation about x/y at 1 m: < 5°",
    "6.5": "dots, rotation about z at 1 m: < 3°",
    "6.6": "one 6.5 cm 4×4 code, x/y at 1.9 m: < 3 cm",
    "6.7": "one code, z: up to 9 % at ~2 m, 6 % at 20 cm",
    "6.8": "one code, rotation about x/y: errors up to ~10 % (coplanar points)",
    "6.9": "one code, rotation about z: ~2°",
    "6.10": "on the Odroid: ArUco clearly faster than dots, a small drop as markers are added",
    "6.11": "over 30 min: ArUco flat, colour dots +10 MB",
}


def _versions() -> dict:
    out = {"python": sys.version.split()[0], "opencv": cv2.__version__,
           "numpy": np.__version__}
    for mod in ("drovisio", "pupil_apriltags", "matplotlib"):
        try:
            out[mod] = version(mod.replace("_", "-"))
        except Exception:  # noqa: BLE001 - not installed
            out[mod] = "not installed"
    return out


def _machine() -> dict:
    return {"system": platform.platform(), "machine": platform.machine(),
            "cpus": os.cpu_count(), "processor": platform.processor() or None}


def _ours(summary: list[dict], fig: str, methods) -> str:
    rows = [s for s in summary if s["figure"] == fig and "p95" in s]
    parts = []
    for m in dict.fromkeys(s["method"] for s in rows):
        mine = [s for s in rows if s["method"] == m]
        worst = max(mine, key=lambda s: s["p95"])
        amb = sum(s["ambiguous"] for s in summary if s["figure"] == fig and s["method"] == m)
        unit = {"xy_cm": " cm", "z_pct": " %"}.get(worst["error"], "°")
        parts.append(f"{methods[m].label}: p95 ≤ {worst['p95']:.2f}{unit} (worst step "
                     f"{worst['layout']}, {worst['vary']} {worst['value']:g})"
                     + (f"; {amb} pose(s) flagged ambiguous" if amb else ""))
    return "; ".join(parts) or "—"


def write_report(result, out: Path, command: str, protocol_text: str) -> dict:
    """Write ``report.html``, ``frames.jsonl``, ``summary.json`` and the figures into ``out``;
    returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(result.records)
    drawn = {}
    for fig in figure_ids(result):
        drawn[fig] = box_figure(fig, result.records, METHODS, result.not_applicable,
                                out / f"fig-{fig}.png")
    if result.speed:
        drawn["6.10"] = fps_figure(result.speed, METHODS, out / "fig-6.10.png")
    if result.memory:
        drawn["6.11"] = memory_figure(result.memory, METHODS, out / "fig-6.11.png")
    growth = {m: round(s[-1][1] - s[0][1], 2) for m, s in result.memory.items() if s}
    data = {"schema": "drovisio/study-report@1", "protocol": result.protocol.name,
            "seconds": round(result.seconds, 1), "command": command, "versions": _versions(),
            "machine": _machine(), "skipped": result.skipped,
            "not_applicable": result.not_applicable, "left_out": result.left_out,
            "frames": len({(r["step"], r["frame"]) for r in result.records}),
            "summary": summary, "speed": result.speed, "memory_growth_mb": growth,
            "landing": result.landing,
            "figures": drawn,
            "thesis": {f: {"thesis": t, "ours": _ours(summary, f, METHODS)}
                       for f, t in THESIS.items()}}
    lines = "".join(json.dumps(r, separators=(",", ":")) + "\n" for r in result.records)
    atomic_write_text(out / "frames.jsonl", lines, allow_empty=True)
    atomic_write_text(out / "summary.json", json.dumps(data, indent=1) + "\n")
    atomic_write_bytes(out / "report.html", _html(data, out, protocol_text).encode("utf-8"))
    return data


def _img(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _html(data: dict, out: Path, protocol_text: str) -> str:
    e = html.escape
    figs = []
    for fig in data["figures"]:
        f = out / f"fig-{fig}.png"
        if f.is_file():
            figs.append(f'<figure id="fig-{e(fig)}"><div class="scroll"><img alt="Figure '
                        f'{e(fig)}" src="{_img(f)}"></div><figcaption>Fig. {e(fig)} — thesis: {e(THESIS.get(fig, ""))}'
                        "</figcaption></figure>")
    rows = "".join(f"<tr><td>{e(f)}</td><td>{e(v['thesis'])}</td><td>{e(v['ours'])}</td></tr>"
                   for f, v in data["thesis"].items())
    speed = "".join(f"<tr><td>{e(s['method'])}</td><td>{e(s['layout'])}</td><td>{s['bricks']}"
                    f"</td><td>{s['fps']:.0f}</td></tr>" for s in data["speed"])
    skipped = "".join(f"<li>{e(s)}</li>" for s in data["skipped"]) or "<li>none</li>"
    left = "".join(f"<li>{e(m)}: {e(w)}</li>" for m, w in data["left_out"].items())
    na = "".join(f"<li>{e(lay)}: {e(m)} — {e(w)}</li>" for lay, d in
                 data["not_applicable"].items() for m, w in d.items())
    land = "".join(
        f"<tr><td>{e(x['layout'])}</td><td>{x['tilt_deg']:.0f}°</td><td>{x['rate_hz']:g}</td>"
        f"<td>{x['median_error_m'] * 100:.1f}</td><td>{x['p90_error_m'] * 100:.1f}</td>"
        f"<td>{x['initialised'] * 100:.0f}%</td><td>"
        + ("–" if x["blind_height_m"] is None else f"{x['blind_height_m']:.2f}")
        + "</td></tr>" for x in data.get("landing", []))
    mem = ", ".join(f"{e(m)} {g:+.2f} MB" for m, g in data["memory_growth_mb"].items()) or "—"
    ver = ", ".join(f"{e(k)} {e(str(v))}" for k, v in data["versions"].items())
    mach = ", ".join(f"{e(k)}: {e(str(v))}" for k, v in data["machine"].items())
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport"
content="width=device-width, initial-scale=1"><title>Drovisio study: {e(data['protocol'])}</title>
<style>body{{font:16px/1.5 system-ui,sans-serif;max-width:70rem;margin:0 auto;padding:1rem;
color:#111}} p,li,figcaption{{overflow-wrap:break-word}} img{{max-width:100%;border:1px solid #999}}
table{{border-collapse:collapse}} .scroll{{overflow-x:auto;max-width:100%}}
td,th{{border:1px solid #999;padding:.25rem .5rem;text-align:left;vertical-align:top}}
pre{{background:#f2f2f2;padding:.75rem;overflow-x:auto;white-space:pre-wrap}}
figure{{margin:1.5rem 0}} code{{overflow-wrap:anywhere}}
@media (max-width:40rem){{.scroll img{{max-width:none;width:40rem}}}}</style>
</head><body>
<h1>Drovisio study: {e(data['protocol'])}</h1>
<p>{data['frames']} frames, {data['seconds']:.0f} s. Reproduce with: <code>{e(data['command'])}</code></p>
<p>Set-up of the thesis: the camera faces the markers (z through the camera, x/y in their
plane). "Drovisio" is given what a drone's autopilot gives it, gravity (the brick's down in the
camera frame, with a 1° attitude error drawn per frame); "Drovisio, image only" is the same
detector without it, as plain OpenCV and AprilTag 3 are. Without gravity a code seen
square-on cannot be told from its mirror image: Drovisio flags those poses ambiguous (counted
in each figure, and drawn); OpenCV and AprilTag 3 flag nothing.</p>
<h2>The thesis beside this study</h2>
<div class="scroll"><table><tr><th>Fig.</th><th>Thesis (Logitech C270, Odroid)</th><th>This study</th></tr>{rows}</table></div>
<h2>Figures</h2>{''.join(figs)}
<h2>Frame rate (Fig. 6.10)</h2>
<div class="scroll"><table><tr><th>method</th><th>layout</th><th>bricks</th><th>frames/s</th></tr>{speed}</table></div>
<p>Memory over the run (Fig. 6.11), growth from the start: {mem}</p>
<h2>Precision landing (ArduPilot model)</h2>
<p>LAND-mode descents onto the brick with ArduPilot's precision landing fed by Drovisio at the
frame rate above (PLND_LAG equal to a 50 ms latency, initialisation after updates at most
0.5 s apart for 2 s, 2 s target timeout, descent on the last estimate once the brick leaves
the picture), 3 m/s wind, camera 8 cm ahead of the body origin; blind height: the camera's
height above the brick when it leaves the picture.</p>
<div class="scroll"><table><tr><th>layout</th><th>camera tilt</th><th>detections/s</th>
<th>touchdown error median (cm)</th><th>p90 (cm)</th><th>filter initialised</th>
<th>blind height (m)</th></tr>{land or '<tr><td colspan="7">not run</td></tr>'}</table></div>
<h2>What was left out</h2><ul>{left or '<li>no method</li>'}</ul>
<h3>Methods that cannot read a layout</h3><ul>{na or '<li>none</li>'}</ul>
<h3>Steps skipped</h3><ul>{skipped}</ul>
<h2>Protocol</h2><pre>{e(protocol_text)}</pre>
<h2>Versions and machine</h2><p>{ver}</p><p>{mach}</p>
</body></html>
"""
