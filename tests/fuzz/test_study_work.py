"""Class: work estimated before it starts — a study protocol's total work (steps × frames ×
image size × samples, plus every method reading every frame) is refused in one line over
:attr:`~drovisio.errors.Limits.max_work_samples`, before any frame is rendered or any file
is written; the shipped protocols stay well under it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from drovisio.camera import Camera
from drovisio.errors import LIMITS, InputError
from drovisio.study.protocol import default_protocol
from drovisio.synth import check_render_work

REPO = Path(__file__).resolve().parents[2]


def _protocol(tmp_path: Path, steps: int, frames: int) -> Path:
    p = tmp_path / "big.yaml"
    p.write_text(yaml.safe_dump({
        "schema": "drovisio/study-protocol@1", "name": "big",
        "layouts": [{"name": "code", "layout": "drick-aruco-centre"}],
        "steps": [{"figure": "6.3", "layout": "code", "vary": "distance",
                   "value": 1.0 + 0.001 * i, "frames": frames} for i in range(steps)]}))
    return p


def test_the_estimate_is_the_sum_of_renders_and_reads(ledger):
    ledger.tried_one("limits: total work")
    cam = Camera.drone_webcam()
    px = cam.width * cam.height
    assert check_render_work(cam, 2, 10, 12, 3) == 10 * px * 4 + 12 * px * 3
    full = default_protocol()
    n = sum(s.frames for s in full.steps)
    need = check_render_work(cam, 2, n, n, 6)
    # the full default study is a few G samples: far under the cap, which it must stay
    assert need < LIMITS.max_work_samples / 10
    with pytest.raises(InputError, match=r"big.yaml: steps and camera: 20000000 rendered"):
        check_render_work(cam, 2, 20_000_000, 20_000_000, 6, "big.yaml: steps and camera")


@pytest.mark.parametrize(("steps", "frames"), [(2000, 10_000), (400, 10_000)])
def test_study_run_refuses_a_protocol_over_the_work_cap(tmp_path, steps, frames, ledger):
    ledger.tried_one("limits: total work")
    proto = _protocol(tmp_path, steps, frames)
    out = tmp_path / "report"
    r = subprocess.run([sys.executable, "-m", "drovisio", "study", "run", "--protocol",
                        str(proto), "--out", str(out)], capture_output=True, text=True,
                       timeout=300, cwd=REPO)
    assert r.returncode == 2, r.stderr[-2000:]
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("drovisio")]
    assert len(err) == 1 and "Traceback" not in r.stderr
    assert f"{proto}: steps and camera: {steps * frames} rendered" in err[0]
    assert "DROVISIO_MAX_WORK_GSAMPLES" in err[0]
    assert not any(out.rglob("*.*"))  # nothing was rendered or written
