"""The ``pipestitch`` command (typer): parse options, call the pipeline, map errors to
exit codes (0 success, 2 bad input, 1 processing failure; SPEC).

May import: :mod:`pipestitch.pipeline`, :mod:`pipestitch.api`, ``config``, ``errors``
and the option types of the stages (scenarios, calibration boards). Must not do any
work itself: each command is a few lines around one pipeline call.
"""

from __future__ import annotations

import sys

__all__ = ["main"]


def main() -> None:
    """The console script: the app, imported here so that Ctrl-C at any moment, even
    while the libraries load, ends with one line and exit code 130, not a traceback."""
    try:
        from pipestitch.cli.app import main as app_main

        app_main()
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        quiet_shutdown()
        raise SystemExit(130) from None
    except SystemExit as exc:
        if exc.code == 130:
            quiet_shutdown()
        raise


def quiet_shutdown() -> None:
    """After an interrupt, let nothing but the one line reach the user: objects that a
    library was building when Ctrl-C came (numba's LLVM passes, mid-compile) are
    finalised at exit and their errors would print as tracebacks; they are dropped."""
    sys.unraisablehook = lambda _unraisable: None
