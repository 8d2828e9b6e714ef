"""The ``pipestitch`` command (typer): parse options, call the pipeline, map errors to
exit codes (0 success, 2 bad input, 1 processing failure; SPEC).

May import: :mod:`pipestitch.pipeline`, :mod:`pipestitch.api`, ``config``, ``errors``
and the option types of the stages (scenarios, calibration boards). Must not do any
work itself: each command is a few lines around one pipeline call.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from types import FrameType
from typing import NoReturn

__all__ = ["interrupted", "main"]

#: BLAS thread pools the command leaves at one thread unless the user set them.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def main() -> None:
    """The console script: the app, imported here so that Ctrl-C at any moment, even
    while the libraries load, ends with one line and exit code 130, not a traceback."""
    single_threaded_blas()
    noting = (threading.current_thread() is threading.main_thread()
              and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if noting:   # not where SIGINT is ignored (a background job) or set by the caller
        signal.signal(signal.SIGINT, _note_interrupt)
    try:
        from pipestitch.cli.app import main as app_main

        app_main()
    except KeyboardInterrupt:
        _interrupted_exit()
    except SystemExit as exc:
        if exc.code == 130:
            quiet_shutdown()
        raise
    except Exception as exc:
        if interrupted(exc):   # while the app loaded
            _interrupted_exit()
        raise
    finally:
        if noting:
            signal.signal(signal.SIGINT, signal.default_int_handler)


_interrupts: list[int] = []   # the SIGINTs this process received (the console script's)


def _note_interrupt(signum: int, frame: FrameType | None) -> None:
    """Python's own Ctrl-C handler (raise KeyboardInterrupt), noting that it came."""
    _interrupts.append(signum)
    signal.default_int_handler(signum, frame)


def interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` is Ctrl-C in another form: raised after Ctrl-C came to this
    process (the ``pipestitch`` command's; some libraries turn the KeyboardInterrupt
    raised inside their callbacks into errors of their own, as pydantic-core does with a
    ``SchemaError`` while a model class is built, as the command's first imports do), or
    while a KeyboardInterrupt was being handled (its cause or context chain holds one:
    a clean-up that failed on the way out)."""
    if _interrupts:
        return True
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def _interrupted_exit() -> NoReturn:
    sys.stderr.write("interrupted\n")
    quiet_shutdown()
    raise SystemExit(130) from None


def single_threaded_blas() -> None:
    """Give numpy's and scipy's BLAS one thread each, before they load, unless the
    environment already says how many.

    A run spreads its frames over its own worker threads; the matrices it hands to BLAS
    are small (normal equations of a few hundred unknowns at most), and an idle
    OpenBLAS worker spins for a while after each call it shared, taking a core from the
    run's threads (measured: 0.3-0.4 s of CPU on a 60-pair run, a busy second thread
    while the command imports). The variables reach the worker processes of
    ``pipestitch batch`` too; a user who wants threaded BLAS sets them.
    """
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def quiet_shutdown() -> None:
    """After an interrupt, let nothing but the one line reach the user: objects that a
    library was building when Ctrl-C came (numba's LLVM passes, mid-compile) are
    finalised at exit and their errors would print as tracebacks; they are dropped."""
    sys.unraisablehook = lambda _unraisable: None
