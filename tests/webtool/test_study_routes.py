"""The Study page's API: a study of the shipped recorded-style protocol started from the
page, its progress, its report listed and served (figures embedded), and nothing else."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient

from webtool.app import create_app
from webtool.settings import Settings

LOCAL = "http://127.0.0.1:8080"


def test_start_the_sample_study_and_read_its_report(tmp_path):
    app = create_app(Settings(study_dir=tmp_path / "study", calibration_dir=tmp_path / "cal"))
    with TestClient(app, base_url=LOCAL) as c:
        assert c.get("/api/study/reports").json()["reports"] == []
        assert c.get("/study").status_code == 200
        r = c.post("/api/study/start")
        assert r.status_code == 202 and r.json()["running"] is True
        assert c.post("/api/study/start").status_code == 409       # one at a time
        seen = set()
        deadline = time.monotonic() + 1200   # a bound, not a timing: 297 s on a busy 2-core machine
        while time.monotonic() < deadline:
            p = c.get("/api/study/progress").json()
            seen.add(round(p["fraction"], 1))
            if not p["running"]:
                break
            time.sleep(0.5)
        assert p["error"] is None and p["fraction"] == 1.0 and p["report"], p
        assert len(seen) >= 3                                      # it moved
        reports = c.get("/api/study/reports").json()["reports"]
        assert [x["name"] for x in reports] == [p["report"]]
        assert reports[0]["protocol"] == "recorded example" and reports[0]["frames"] == 24
        html = c.get(f"/study/reports/{p['report']}/report.html")
        assert html.status_code == 200 and html.text.count("data:image/png;base64,") >= 4
        fig = c.get(f"/study/reports/{p['report']}/fig-6.7.png")
        assert fig.status_code == 200 and fig.content[:4] == b"\x89PNG"
        for bad in (f"{p['report']}/summary.json", f"..%2F{p['report']}/report.html",
                    "nothing/report.html", f"{p['report']}/fig-6.7.png.bak"):
            assert c.get(f"/study/reports/{bad}").status_code == 404, bad
