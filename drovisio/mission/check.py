"""Safety rules checked on a simulated run, and the fault table of ``drovisio mission check``.

Rules (each one a function of a :class:`~drovisio.mission.sim.Trace`, so the hypothesis
tests and the CLI check the very same thing):

``retries``       no phase of a brick fails more than ``retries`` times, and no phase is
                  attempted more than ``retries`` times (3 in the thesis: two retries).
``safe_zone``     after the ``retries``-th failure of a phase, or a disagreement, the machine
                  only goes to the safe zone, lands and shuts down; the run ends in SHUTDOWN
                  with the drone (truth) on the ground inside the safe zone.
``yaw_descent``   never a descent onto a target while the machine's yaw error exceeds
                  ``align_yaw_tolerance_deg``: every tick of a vision-guided descent whose
                  setpoint goes down has ``|yaw error| <= tolerance``, and the blind descent
                  starts only within it.
``geofence``      every setpoint is inside ``site.bounds``.
``placement``     (runs that complete) every brick within ``placement_tolerance`` of its plan
                  (truth: horizontal distance and yaw modulo 180°).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drovisio.mission.faults import CHECK_FAULTS, FaultCase
from drovisio.mission.machine import SAFE_STATES, State
from drovisio.mission.scenario import Scenario
from drovisio.mission.sim import SimParams, Trace, simulate

__all__ = ["RULES", "RuleResult", "check_rules", "CaseResult", "run_case", "run_fault_table",
           "format_table", "narrate", "landing_lines"]

RULES = ("retries", "safe_zone", "yaw_descent", "geofence", "placement")


@dataclass
class RuleResult:
    rule: str
    held: bool
    detail: str = ""


def _rule_retries(tr: Trace) -> RuleResult:
    n = tr.scenario.thresholds.retries
    worst: dict[tuple[str, str], int] = {}
    for e in tr.events("phase_failed"):
        key = (e["phase"], e["brick"])
        worst[key] = max(worst.get(key, 0), e["failure"])
    attempts: dict[tuple[str, str], int] = {}
    for e in tr.events("retry"):
        key = (e["phase"], e["brick"])
        attempts[key] = max(attempts.get(key, 1), e["attempt"])
    bad = [f"{p} of {b}: {k} failures" for (p, b), k in worst.items() if k > n]
    bad += [f"{p} of {b}: attempt {k}" for (p, b), k in attempts.items() if k > n]
    most = max(list(worst.values()) + [0])
    return RuleResult("retries", not bad, "; ".join(bad) or f"at most {most} failure(s) of a "
                                                          f"phase (limit {n})")


def _safe_zone_trigger(tr: Trace) -> tuple[float, str] | None:
    """The first event that must send the drone to the safe zone: (time, kind)."""
    n = tr.scenario.thresholds.retries
    for tk in tr.ticks:
        for e in tk.events:
            if (e["kind"] == "phase_failed" and e["failure"] >= n) or e["kind"] == "disagreement":
                return tk.t, e["kind"]
    return None


def _rule_safe_zone(tr: Trace) -> RuleResult:
    trigger = _safe_zone_trigger(tr)
    if trigger is None:
        return RuleResult("safe_zone", True, "not triggered")
    trigger_t, why = trigger
    after = [tk for tk in tr.ticks if tk.t > trigger_t]
    wrong = sorted({tk.state for tk in after if tk.state not in {s.value for s in SAFE_STATES}})
    if wrong:
        return RuleResult("safe_zone", False, f"after {why}: went to {', '.join(wrong)}")
    if tr.final_state != State.SHUTDOWN.value:
        return RuleResult("safe_zone", False, f"after {why}: ended in {tr.final_state}, not "
                                              "SHUTDOWN (time out?)")
    return _shut_down_in_safe_zone(tr, why)


def _shut_down_in_safe_zone(tr: Trace, why: str) -> RuleResult:
    """Where the run that went to the safe zone shut down."""
    scn = tr.scenario
    last = tr.ticks[-1]
    sz = scn.site.safe_zone
    d = math.dist(last.position[:2], sz.center)
    landed = last.position[2] <= scn.drone.gear_height_m + scn.drone.picker_depth_m + 0.2
    if d > sz.radius or not landed:
        return RuleResult("safe_zone", False, f"after {why}: shut down {d:.2f} m from the safe "
                                              f"zone centre (radius {sz.radius} m), "
                                              f"z = {last.position[2]:.2f} m")
    return RuleResult("safe_zone", True, f"after {why}: shut down {d:.2f} m inside the safe "
                                         "zone")


def _rule_yaw_descent(tr: Trace) -> RuleResult:
    tol = math.radians(tr.scenario.thresholds.align_yaw_tolerance_deg)
    vision_descent = {State.DESCEND_BRICK.value, State.DESCEND_SLOT.value}
    prev_z = None
    worst = 0.0
    for tk in tr.ticks:
        z = tk.setpoint["position"][2] if tk.setpoint else None
        descending = z is not None and prev_z is not None and z < prev_z - 1e-9
        if tk.state in vision_descent and descending:
            ye = tk.telemetry.get("yaw_error")
            if ye is None:
                return RuleResult("yaw_descent", False, f"t={tk.t}: descending with no yaw "
                                                        "estimate")
            worst = max(worst, abs(ye))
            if abs(ye) > tol + 1e-9:
                return RuleResult("yaw_descent", False, f"t={tk.t}: descending with yaw error "
                                                        f"{math.degrees(ye):.2f}°")
        for e in tk.events:
            if e["kind"] == "blind" and abs(e["yaw_error_deg"]) > math.degrees(tol) + 1e-6:
                return RuleResult("yaw_descent", False, f"t={tk.t}: blind descent started with "
                                                        f"yaw error {e['yaw_error_deg']}°")
        prev_z = z
    return RuleResult("yaw_descent", True, f"worst yaw error while descending "
                                           f"{math.degrees(worst):.2f}° (limit "
                                           f"{math.degrees(tol):.1f}°)")


def _rule_geofence(tr: Trace) -> RuleResult:
    b = tr.scenario.site.bounds
    for tk in tr.ticks:
        if tk.setpoint and not b.contains(tk.setpoint["position"]):
            return RuleResult("geofence", False, f"t={tk.t}: setpoint {tk.setpoint['position']} "
                                                 "outside site.bounds")
    return RuleResult("geofence", True, "all setpoints inside the site")


def _rule_placement(tr: Trace) -> RuleResult:
    tol = tr.scenario.placement_tolerance
    if not tr.placements:
        return RuleResult("placement", True, "no brick placed")
    pos, yaw = tr.placement_errors()
    bad = [f"{b}: {p['error_m'] * 100:.1f} cm / {p['yaw_error_deg']:.1f}°"
           for b, p in tr.placements.items()
           if p["error_m"] > tol.position_m or p["yaw_error_deg"] > tol.yaw_deg]
    detail = (f"{len(pos)} placed, max {pos.max() * 100:.1f} cm / {yaw.max():.1f}°")
    return RuleResult("placement", not bad, "; ".join(bad) or detail)


def check_rules(tr: Trace) -> list[RuleResult]:
    """Every rule of the module docstring, on one run."""
    return [_rule_retries(tr), _rule_safe_zone(tr), _rule_yaw_descent(tr), _rule_geofence(tr),
            _rule_placement(tr)]


_PHRASES: dict[str, Callable[[dict[str, Any]], str]] = {
    "misaligned": lambda e: f"stopped descent and realigned ({e['brick']})",
    "disagreement": lambda e: f"TS and vision disagree by {e['distance_m']:.2f} m",
    "placement_out_of_tolerance": lambda e: f"{e['brick']} found off its plan",
    "geofence": lambda e: "geofence guard",
    "safe_zone": lambda e: "→ safe zone",
}
"""How the narrative tells an event (phase failures are gathered per phase and brick)."""


def _narrative_parts(tr: Trace) -> tuple[list[str], dict[tuple[str, str], list[str]]]:
    """The events told, in order (a placeholder ``@fail:PHASE:BRICK`` where a phase of a
    brick first failed), and each such phase's failure reasons."""
    parts: list[str] = []
    fails: dict[tuple[str, str], list[str]] = {}
    for e in tr.events():
        k = e["kind"]
        if k == "phase_failed":
            key = (e["phase"], e["brick"])
            if key not in fails:
                fails[key] = []
                parts.append(f"@fail:{e['phase']}:{e['brick']}")
            fails[key].append(e["reason"])
        elif k in _PHRASES:
            parts.append(_PHRASES[k](e))
    return parts, fails


def narrate(tr: Trace) -> str:
    """What the machine did, in a line: failures per phase, realignments, the abort reason,
    then the outcome."""
    n = tr.scenario.thresholds.retries
    parts, fails = _narrative_parts(tr)
    out: list[str] = []
    for p in parts:
        if p.startswith("@fail:"):
            _, phase, brick = p.split(":", 2)
            reasons = fails[(phase, brick)]
            uniq = list(dict.fromkeys(reasons))
            retried = "" if len(reasons) >= n else ", retried"
            p = f"{phase} of {brick} failed {len(reasons)}/{n} ({'; '.join(uniq)}){retried}"
        if not out or out[-1] != p:
            out.append(p)
    n_placed = sum(1 for p in tr.placements.values() if p.get("verified"))
    end = {"DONE": f"completed {n_placed}/{len(tr.scenario.order)} bricks, landed home",
           "SHUTDOWN": f"landed in the safe zone, shut down ({n_placed} placed)"}.get(
        tr.final_state, f"stopped in {tr.final_state}")
    return "; ".join(out + [end])


@dataclass
class CaseResult:
    case: FaultCase
    trace: Trace
    rules: list[RuleResult]
    outcome: str
    as_expected: bool
    narrative: str

    @property
    def all_held(self) -> bool:
        return all(r.held for r in self.rules)


def run_case(scn: Scenario, case: FaultCase, params: SimParams | None = None) -> CaseResult:
    case = case.for_order(scn.order)
    tr = simulate(scn, case.faults, params)
    rules = check_rules(tr)
    outcome = {"DONE": "completed", "SHUTDOWN": "safe_zone"}.get(tr.final_state, tr.final_state)
    if outcome != "completed":  # placement only judged on completed runs
        rules = [r if r.rule != "placement" or r.held else
                 RuleResult("placement", True, "not judged: run did not complete (" + r.detail
                            + ")") for r in rules]
    return CaseResult(case, tr, rules, outcome, outcome == case.expect, narrate(tr))


def run_fault_table(scn: Scenario, cases=CHECK_FAULTS, params: SimParams | None = None,
                    progress=None) -> list[CaseResult]:
    out = []
    for case in cases:
        res = run_case(scn, case, params)
        if progress:
            progress(f"  {case.name}: {res.outcome}")
        out.append(res)
    return out


def format_table(results: list[CaseResult]) -> str:
    """A plain-text table: fault, what the machine did, outcome, rules."""
    rows = [("fault", "what the machine did", "outcome (expected)", "safety rules")]
    for r in results:
        broken = [x.rule for x in r.rules if not x.held]
        rules = "all held" if not broken else "BROKEN: " + ", ".join(broken)
        rows.append((r.case.name, r.narrative,
                     f"{r.outcome} ({'ok' if r.as_expected else 'expected ' + r.case.expect})",
                     rules))
    w = [min(max(len(row[i]) for row in rows), cap) for i, cap in enumerate((44, 130, 30, 30))]
    lines = []
    for k, row in enumerate(rows):
        cells = []
        for i, cell in enumerate(row):
            cells.append(cell if len(cell) <= w[i] else cell[:w[i] - 1] + "…")
        lines.append(" | ".join(c.ljust(w[i]) for i, c in enumerate(cells)).rstrip())
        if k == 0:
            lines.append("-+-".join("-" * x for x in w))
    return "\n".join(lines)


def landing_lines(tr: Trace) -> list[str]:
    """One line per pick descent of a run (:attr:`Trace.landings`): where it touched down
    (truth), what it led to, and with the autopilot's precision landing whether its filter
    initialised and where the brick left the picture; then a warning when the filter never
    initialised on a descent."""
    scn = tr.scenario
    ap = scn.autopilot
    lines: list[str] = []
    never: list[str] = []
    for d in tr.landings:
        line = (f"pick descent onto {d['brick']} (t={d['t_start']:.1f}-{d['t_end']:.1f} s): "
                f"{d['error_m'] * 100:.1f} cm from the brick's centre when it ended "
                f"({d['outcome']})")
        if ap.precision_landing:
            if d["initialised"]:
                line += f"; precision-landing filter initialised ({d['measurements']} targets"
                if d["estimate_error_m"] is not None:
                    line += f", its estimate then {d['estimate_error_m'] * 100:.1f} cm off"
                line += ")"
            else:
                never.append(d["brick"])
                line += (f"; precision-landing filter NEVER initialised ({d['measurements']} "
                         f"targets, {d['init_failures']} Init Failed): it landed on the "
                         "mission's own setpoint")
            seen = d["last_seen_camera_height_m"]
            blind = d["blind_height_m"]
            line += ("; brick last seen " + (f"{seen:.2f} m" if seen is not None else "never")
                     + " above it (camera), it leaves the picture "
                     + (f"{blind:.2f} m above it" if blind is not None else "never")
                     + " with this lens and mount")
        lines.append(line)
    if never:
        rate = ap.rate_hz if ap.rate_hz is not None else tr.params.vision_params.rate_hz
        prob = ap.detect_prob if ap.detect_prob is not None else \
            1.0 - tr.params.vision_params.miss_prob
        lines.append(f"WARNING: ArduPilot's precision-landing filter never initialised on "
                     f"{', '.join(dict.fromkeys(never))}: it needs updates at most 0.5 s apart "
                     f"for 2 s (2 Hz); the pipeline gives {rate * prob:.1f} detections a second "
                     "(autopilot.rate_hz, autopilot.detect_prob)")
    return lines
