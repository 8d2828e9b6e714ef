"""The ``pipestitch`` command (typer): parse options, call the pipeline, map errors to
exit codes (0 success, 2 bad input, 1 processing failure; SPEC).

May import: :mod:`pipestitch.pipeline`, :mod:`pipestitch.api`, ``config``, ``errors``
and the option types of the stages (scenarios, calibration boards). Must not do any
work itself: each command is a few lines around one pipeline call.
"""

from pipestitch.cli.app import main

__all__ = ["main"]
