"""``drovisio study``: the thesis's evaluation (chapter 6) on renders or on the user's own
recordings, Drovisio beside plain OpenCV and AprilTag 3.

Parts, one module each: :mod:`.protocol` (the protocol file and the default one),
:mod:`.frames` (rendered and recorded steps), :mod:`.methods` (the detectors compared),
:mod:`.analysis` (errors per frame, summaries), :mod:`.figures` (matplotlib),
:mod:`.report` (HTML, JSON Lines, JSON), :mod:`.run` (the command).
"""
