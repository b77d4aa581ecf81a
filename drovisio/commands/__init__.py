"""The ``drovisio`` commands, one module per command (``calibrate`` also holds ``calibrate
board`` and ``calibrate mount``). Each declares its face beside its code: ``COMMAND`` (summary,
description, example; :class:`drovisio.arguments.Command`), ``add_arguments(parser)`` and
``run(args) -> int``. :mod:`drovisio.cli` lists them and handles every error once.

A command module is imported by ``drovisio --help``: its own working modules (OpenCV, the
detectors, the pipeline) are imported inside the functions that run it.
"""
