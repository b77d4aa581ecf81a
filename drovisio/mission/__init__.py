"""Pick-and-place mission: the thesis's strategy (ch. 8) as an executable, checked state machine.

* :mod:`.frames` — the site frame (x east, y north, z up, metres) and heading conventions.
* :mod:`.scenario` — the scenario file (pydantic schema, single source of truth).
* :mod:`.machine` — states and transitions as data; a pure step function on a given clock.
* :mod:`.sim` — kinematic drone, total station, picker; vision from :mod:`.vision` (a detector
  model, or renders through the real detectors).
* :mod:`.faults` — injected faults; :mod:`.check` — safety rules and the fault table.
* :mod:`.diagram` — Mermaid / Graphviz DOT / SVG of the machine, generated from the table.
* :mod:`.record` — JSON Lines recording of a simulated run (replayable in 3D).
"""
