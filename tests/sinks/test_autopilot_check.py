"""`drovisio autopilot check` against a scripted vehicle: each wrong parameter named with its fix."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from drovisio.autopilot.check import Facts, evaluate, plnd_lag_for, verdict
from drovisio.autopilot.session import read_vehicle
from drovisio.cli import main

REPO = Path(__file__).resolve().parents[2]
APPROACH = REPO / "sample_sessions" / "approach"

WRONG = [("PLND_ENABLED", 0, "1"), ("PLND_TYPE", 2, "1"), ("PLND_EST_TYPE", 0, "1"),
         ("PLND_ORIENT", 0, "25"), ("PLND_YAW_ALIGN", 90, "0"), ("PLND_CAM_POS_X", 0.08, "0"),
         ("PLND_CAM_POS_Y", -0.02, "0"), ("PLND_CAM_POS_Z", 0.05, "0"), ("PLND_LAG", 0.2, "0.05")]


def _by_item(findings):
    return {f.item: f for f in findings}


@pytest.mark.parametrize("name,value,fix", WRONG)
def test_each_wrong_ardupilot_parameter_is_named_with_its_fix(vehicle, ardupilot_ok, name,
                                                              value, fix):
    params = dict(ardupilot_ok, **{name: value})
    v = vehicle(params=params)
    facts = read_vehicle(f"udpout:127.0.0.1:{v.port}", "ardupilot", timeout_s=3, stream_s=0.5)
    assert facts.params[name] == pytest.approx(value)
    facts.latency_s = 0.05
    got = _by_item(evaluate(facts))
    assert got[name].status == "wrong"
    assert f"{value:g} → set {fix}" in got[name].text
    others = [f for f in got.values() if f.status == "wrong"]
    assert others == [got[name]]


def test_right_ardupilot_parameters_say_ok(vehicle, ardupilot_ok, capsys):
    v = vehicle(params=ardupilot_ok)
    code = main(["autopilot", "check", f"udpout:127.0.0.1:{v.port}", "--latency-ms", "50",
                 "--timeout", "3"])
    out = capsys.readouterr().out.splitlines()
    assert code == 0, out
    for name in ardupilot_ok:
        assert any(line.startswith("ok") and f" {name}: " in line for line in out), name
    assert any(line.startswith("ok") and "ATTITUDE" in line for line in out)
    assert any("PLND_LAG = 0.05" in line for line in out)


def test_px4_vehicle_with_the_ardupilot_flavour_is_wrong(vehicle, px4_ok, capsys):
    v = vehicle(autopilot=12, params=px4_ok)
    code = main(["autopilot", "check", f"udpout:127.0.0.1:{v.port}", "--timeout", "3"])
    out = capsys.readouterr().out
    assert code == 1
    assert "wrong   autopilot: PX4 (system 1)" in out and "--autopilot px4" in out
    code = main(["autopilot", "check", f"udpout:127.0.0.1:{v.port}", "--timeout", "3",
                 "--autopilot", "px4"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "ok      PLD_HACC_RAD: 0.05" in out and "LOCAL_POSITION_NED" in out


def test_px4_final_approach_altitude_against_the_blind_height(px4_ok):
    f = Facts(flavour="px4", autopilot=12, system=1, params=dict(px4_ok, PLD_FAPPR_ALT=0.1),
              params_asked=True, blind_height_m=1.67)
    got = _by_item(evaluate(f))
    assert got["PLD_FAPPR_ALT"].status == "wrong" and "set 1.72" in got["PLD_FAPPR_ALT"].text


def test_against_nothing_one_line_within_its_deadline(capsys):
    t0 = time.monotonic()
    code = main(["autopilot", "check", "udpout:127.0.0.1:9", "--timeout", "1"])
    took = time.monotonic() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "no HEARTBEAT from an autopilot within 1 s" in err[0]
    assert took < 60   # bounded (a bound for failures only: the deadline is 1 s)


def test_bad_connection_options_exit_2(capsys):
    assert main(["autopilot", "check", "udpout:127.0.0.1:9?compid=0"]) == 2
    assert "compid: expected a whole number 1-255" in capsys.readouterr().err
    assert main(["autopilot", "check", "udpout:127.0.0.1:9", "--source", "x.mp4"]) == 2
    assert "--source, --camera and --layout go together" in capsys.readouterr().err


def test_detection_rate_below_2hz_is_wrong_and_lag_follows_latency():
    f = Facts(flavour="ardupilot", detection_hz=1.5, latency_s=0.118)
    got = _by_item(evaluate(f))
    assert got["detection rate"].status == "wrong" and "never initialises" in \
        got["detection rate"].text
    assert verdict(evaluate(f)) == 1
    assert got["latency"].text.endswith("PLND_LAG 0.12")
    assert plnd_lag_for(0.004) == 0.02 and plnd_lag_for(0.6) == 0.25
    assert _by_item(evaluate(Facts(flavour="ardupilot", detection_hz=2.5)))[
        "detection rate"].status == "warn"
    assert _by_item(evaluate(Facts(flavour="ardupilot", detection_hz=15.0)))[
        "detection rate"].status == "ok"


def test_measures_latency_rate_and_blind_height_on_the_sample_video(vehicle, ardupilot_ok,
                                                                   capsys):
    v = vehicle(params=dict(ardupilot_ok, PLND_LAG=0.25))
    code = main(["autopilot", "check", f"udpout:127.0.0.1:{v.port}", "--timeout", "3",
                 "--source", str(APPROACH / "approach.mp4"),
                 "--camera", str(REPO / "sample_sessions" / "camera.yaml"),
                 "--layout", str(REPO / "marker_layouts" / "drick-aruco-centre.json"),
                 "--mount", str(APPROACH / "mount.json"), "--seconds", "2"])
    out = capsys.readouterr().out
    lines = {ln[8:].split(":")[0].split()[-1]: ln for ln in out.splitlines()
             if ln.split()[0] in ("ok", "wrong", "warn", "unknown")}
    # the figures depend on this machine's load; what is checked is what follows from them
    # "… 12.3 Hz …" when fast enough, "target measured 1.2 times a second" when not (a
    # loaded machine)
    rate = float(re.search(r"detection rate: (?:target measured )?([0-9.]+)",
                           lines["rate"]).group(1))
    assert 0.0 < rate <= 15.0 * 1.1, out      # never faster than the 15 fps video
    latency_ms = float(lines["latency"].split("capture to send ")[1].split(" ms")[0])
    lag = plnd_lag_for(latency_ms / 1e3)
    assert f"set PLND_LAG = {lag:.2f}" in out
    wrong = abs(0.25 - lag) > max(0.01, 0.25 * lag)
    assert lines["PLND_LAG"].startswith("wrong" if wrong else "ok")
    assert (code == 1) == (wrong or rate < 3.0)
    assert "leaves the picture 1.6" in out or "leaves the picture 1.7" in out


def test_the_measuring_window_opens_with_the_first_frame(monkeypatch):
    """A start-up longer than ``--seconds`` (a source slow to open, the detectors' kernels
    loading on a busy machine) is not measured as no detection at all: the window opens with
    the first frame (it closed before the first frame, before)."""
    import argparse

    import numpy as np

    from drovisio import startup
    from drovisio.commands.autopilot import measure_pipeline
    from drovisio.detect.result import BrickPose
    from drovisio.pipeline import Pipeline
    from drovisio.sources import FrameSource, RawFrame

    class SlowToOpen:
        label, finite = "slow camera", False

        def open(self):
            time.sleep(0.5)           # longer than the whole window below

        def read(self):
            time.sleep(0.02)
            return RawFrame(np.zeros((48, 64, 3), np.uint8), 0)

        def close(self):
            pass

    class OneBrick:
        name = "fake"

        def detect(self, image, gravity=None):
            return [BrickPose("drick-aruco-centre", 1, "aruco", np.array([3.1, 0.0, 0.0]),
                              np.array([0.1, 0.0, 1.5]), 0.2, markers=[1],
                              covariance=np.eye(6) * 1e-5)]

    monkeypatch.setattr(startup, "build_pipeline", lambda config, default_sinks=():
                        Pipeline(FrameSource(SlowToOpen()), [OneBrick()]))
    args = argparse.Namespace(source="slow", camera="c.yaml", layout=[], mount=None,
                              target="nearest", autopilot="ardupilot")
    latency, rate = measure_pipeline(args, 0.1)
    assert latency is not None and rate > 0


def test_a_refused_tcp_link_is_one_line_on_stderr_only(capsys):
    assert main(["autopilot", "check", "tcp:127.0.0.1:1", "--timeout", "1"]) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "tcp:127.0.0.1:1: cannot connect to 127.0.0.1:1" in lines[0]


def test_a_tcp_peer_that_closes_the_link_is_one_line_not_a_flood(closing_peer, capfd):
    # pymavlink printed "EOF on TCP socket" at every read of a closed link: hundreds of
    # thousands of lines a second on stdout
    assert main(["autopilot", "check", f"tcp:127.0.0.1:{closing_peer.port}", "--timeout",
                 "2"]) == 2
    cap = capfd.readouterr()
    assert cap.out == ""
    assert cap.err == (f"drovisio autopilot: tcp:127.0.0.1:{closing_peer.port}: "
                       f"127.0.0.1:{closing_peer.port} closed the connection; check that the "
                       "address is a MAVLink TCP server's (the autopilot's, SITL's or "
                       "mavlink-router's) and that no other program holds its connection\n")
