"""``drovisio bench fleet`` (short): every drone's frames reach the station in order, and the
report carries the latency and memory figures of every process."""

from __future__ import annotations

import json

import pytest

from drovisio.bench.fleet import main

pytest.importorskip("zenoh")


def test_short_fleet_run_reports_every_process(tmp_path, capsys):
    out = tmp_path / "fleet.json"
    assert main(["--drones", "2", "--fps", "20", "--minutes", "0.2", "--warmup-minutes", "0.05",
                 "--quiet", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["drones"] == 2 and [d["drone"] for d in r["per_drone"]] == ["drone1", "drone2"]
    for d in r["per_drone"]:
        # 12 s at 20 fps: what the sink published arrives (the first may precede the
        # link); a gap in the frame numbers is one the sink dropped itself (its queue gives
        # way when the machine stalls it), never one the network lost
        assert d["sent"] >= 200 and d["received"] >= 0.8 * d["sent"]
        assert d["missing"] <= d["dropped_in_sink"]
        assert d["growth_mb"] is not None
    assert r["station"]["received"] == sum(d["received"] for d in r["per_drone"])
    assert r["latency_ms"]["frames"] > 100 and r["latency_ms"]["p90"] >= r["latency_ms"]["median"] > 0
    text = capsys.readouterr().out
    assert "latency capture → station" in text and "drone2: sent" in text
