"""The dot benchmark's printed report."""

from __future__ import annotations

import math


def _fmt(v, nd=2):
    if v is None:
        return "–"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.{nd}f}"
    return str(v)


def print_report(rep: dict) -> None:
    """Print the figures of the parts that ran, then the definitions."""
    print("\ndrovisio bench dots — colour-dot bricks")
    print("=" * 78)
    for part, section in (("accuracy", _accuracy), ("hidden", _hidden), ("clutter", _clutter),
                          ("lighting", _lighting), ("timing", _timing), ("kernels", _kernels),
                          ("memory", _memory)):
        if rep.get(part):
            section(rep[part])
    print("\nDefinitions: eligible = ≥ 4 fully visible dots of median size ≥ 6 px (equivalent "
          "diameter); lateral = |(Δx, Δy)| of tvec in the camera frame; depth = |Δz|/z; yaw = "
          "rotation about the brick z of R_trueᵀR_est (mod 180° for rot180_z); flip = > 20° "
          "off (mod symmetry), unflagged = not marked ambiguous; false = no true brick within "
          "8 cm.")


def _accuracy(acc: dict) -> None:
    w = print
    w("\nAccuracy (random scenes 0.4–2 m, tilt ≤ 40°; errors at ≤ 2 m, p95)")
    w(f"{'':24}{'recall':>8}{'rec.6dots':>10}{'lat cm':>8}{'depth %':>8}{'yaw °':>7}"
      f"{'flips':>6}{'unflag':>7}{'ambig':>7}{'false':>6}")
    for k in ("gravity", "no_gravity"):
        r = acc[k]
        w(f"{k + ' (' + str(r['eligible']) + ' bricks)':24}{_fmt(100 * r['recall'], 1):>8}"
          f"{_fmt(100 * r['recall_all_dots'], 1):>10}{_fmt(r['lateral_p95_cm']):>8}"
          f"{_fmt(r['depth_p95_pct']):>8}{_fmt(r['yaw_p95_deg']):>7}{r['flips']:>6}"
          f"{r['unflagged_flips']:>7}{_fmt(100 * r['ambiguous_share'], 0) + '%':>7}"
          f"{r['false_bricks']:>6}")
    r = acc["gravity"]
    w(f"dot centres vs BrickTruth.dot_centers_px: bias ({r['center_bias_px'][0]:+.3f}, "
      f"{r['center_bias_px'][1]:+.3f}) px, rms {r['center_rms_px']:.3f} px over "
      f"{r['centers']} dots")


def _hidden(hid: dict) -> None:
    w = print
    w("\nHidden dots (with gravity)")
    for k, v in hid.items():
        r = v["gravity"]
        w(f"  {k:16} recall {_fmt(100 * r['recall'], 1)}% of {r['eligible']} eligible, "
          f"lat {_fmt(r['lateral_p95_cm'])} cm, depth {_fmt(r['depth_p95_pct'])} %, yaw "
          f"{_fmt(r['yaw_p95_deg'])}°, unflagged flips {r['unflagged_flips']}, false "
          f"{r['false_bricks']}")


def _clutter(clu: dict) -> None:
    w = print
    w("\nClutter without bricks (red cups, blue tarpaulins, photo clutter)")
    for k, v in clu.items():
        w(f"  {k:16} {v['false_bricks']} false bricks in {v['frames']} frames")


def _lighting(lit: dict) -> None:
    w = print
    w("\nLighting (default palette, with gravity)")
    for k, r in lit.items():
        w(f"  {k:22} recall {_fmt(100 * r['recall'], 1):>5}% of {r['eligible']:>3}, lat "
          f"{_fmt(r['lateral_p95_cm'])} cm, depth {_fmt(r['depth_p95_pct'])} %, yaw "
          f"{_fmt(r['yaw_p95_deg'])}°, false {r['false_bricks']}")


def _timing(tim: dict) -> None:
    w = print
    kern = "compiled kernels" if tim.get("compiled_kernels") else \
        "numpy path (no numba, or DROVISIO_NUMBA=0)"
    w(f"\nTiming (medians of {tim.get('repeats', '?')} interleaved runs of "
      f"{tim.get('frames_per_count', '?')} frames per count; minimal pass = cvtColor to "
      f"HSV + one cv2.inRange per colour; OpenCV threads {tim['threads']}; {kern}; wall "
      f"clock, then process CPU time)")
    w(f"{'':12}{'in view':>8}{'found':>7}{'minimal ms':>12}{'detect ms':>11}{'ratio':>7}"
      f"{'vs 1 brick':>11}{'cpu ratio':>10}{'cpu vs 1':>9}{'load':>6}{'numpy ms':>10}")
    for k in ("1_bricks", "5_bricks", "20_bricks"):
        r = tim.get(k)
        if r:
            w(f"{k:12}{_fmt(r['bricks_in_view_median'], 0):>8}"
              f"{_fmt(r['bricks_found_median'], 0):>7}{_fmt(r['minimal_ms'], 3):>12}"
              f"{_fmt(r['detect_ms'], 3):>11}{_fmt(r['ratio']):>7}"
              f"{_fmt(r['vs_1_brick']):>11}{_fmt(r['ratio_cpu']):>10}"
              f"{_fmt(r['vs_1_brick_cpu']):>9}{_fmt(r['loadavg'], 1):>6}"
              f"{_fmt(r.get('numpy_path_ms'), 3):>10}")


def _kernels(ker: dict) -> None:
    w = print
    w("\nCompiled kernels vs what they replace (20-brick frames, medians, µs)")
    if "skipped" in ker:
        w(f"  skipped: {ker['skipped']}")
    for name, r in ker.items():
        if isinstance(r, dict):
            w(f"  {name:74}{r['compiled_us']:9.1f}{r['reference_us']:10.1f}"
              f"  ×{r['speedup']:.1f}")


def _memory(mem: dict) -> None:
    w = print
    w(f"\nMemory: {mem['frames']} frames ({mem['seconds']:.0f} s), RSS after "
      f"{mem['warmup_frames']} warm-up frames {mem['rss_after_warmup_kb']} kB, at the end "
      f"{mem['rss_end_kb']} kB: growth {mem['growth_kb']:+} kB; floor growth "
      f"{mem['floor_growth_kb']:+} kB, trend {mem['trend_kb']:+.0f} kB, samples within a "
      f"{mem['band_kb']} kB band" + (
          f"; Python heap growth {mem['python_heap_growth_kb']:+.1f} kB"
          if mem["python_heap_growth_kb"] is not None else ""))
