"""Error classes shared by the core and the command line, and the exit codes
of ``lmap-drake`` and the scripts (documented in the README):

    0  done
    1  error (a failure of the program or of a device)
    2  bad input (scenario, weights, calibration, output folder, arguments)
    3  episode aborted / no feasible action (the outputs are complete)
  130  interrupted (Ctrl-C, SIGTERM); nothing half-written is left behind

No imports from the rest of the package: every layer may use this module.
"""
from __future__ import annotations

import argparse
import errno
import os

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_BAD_INPUT = 2
EXIT_ABORTED = 3
EXIT_INTERRUPTED = 130


class InputError(Exception):
    """Marker base: the user's input (a file, an argument, a scenario value)
    is wrong; the message says which and where. Exit code 2."""


class OutputError(InputError, OSError):
    """The output folder cannot be written (a file, read-only, exists)."""


class WeightsError(InputError, FileNotFoundError):
    """A weights file is missing or unreadable; the message names it."""


class ConfigError(InputError, ValueError):
    """A configuration value is bad: ``key`` is its dotted path (``shape.ssc.w_sur``),
    ``detail`` what is wrong; the message is the two joined."""

    def __init__(self, key: str, detail: str):
        super().__init__(f"{key} {detail}")
        self.key, self.detail = key, detail


class OneLineArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose usage errors are one line on stderr
    (``prog: error: message (see prog --help)``, no usage block), exit 2.
    Its sub-parsers are of the same class."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {' '.join(message.split())} "
                                  f"(see {self.prog} --help)\n")


class HardwareStationUnavailable(RuntimeError):
    """Raised when the hardware station is requested but not available."""


def OneLine(err: BaseException) -> str:
    """``err`` as one line: its message (or its type when empty)."""
    text = " ".join(str(err).split())
    name = type(err).__name__
    if not text:
        return name
    if isinstance(err, InputError) or name in ("RuntimeError", "ValueError"):
        return text
    return f"{name}: {text}"


_hook_installed = False
_last_written: list = [None]   # the file most recently opened for writing


def _TrackWrites(event: str, args) -> None:
    """Audit hook: remembers the last file opened for writing, so a full
    disk (whose ``OSError`` from ``write`` names no file) can be named."""
    if event == "open" and len(args) == 3 and isinstance(args[2], int) \
            and args[2] & (os.O_WRONLY | os.O_RDWR) and isinstance(args[0], (str, bytes)):
        _last_written[0] = os.fsdecode(args[0])


def _DiskFull(err: BaseException) -> str:
    """' (writing PATH)' for a full disk or quota whose error names no file."""
    if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT) \
            and not err.filename and _last_written[0]:
        return f" (writing {_last_written[0]})"
    return ""


def ExitCode(err: BaseException) -> int:
    if isinstance(err, (KeyboardInterrupt,)):
        return EXIT_INTERRUPTED
    if isinstance(err, InputError):
        return EXIT_BAD_INPUT
    return EXIT_ERROR


def RunMain(main, argv=None, prog: str = "", strip_debug: bool = False) -> int:
    """Calls ``main(argv)`` (``main()`` when ``argv`` is None and
    ``strip_debug``) and turns any exception into one line on stderr and an
    exit code (see the module docstring). ``--debug`` in ``argv`` (or
    ``sys.argv``) prints the traceback as well; with ``strip_debug`` it is
    removed first (for scripts whose parsers do not know it). SIGTERM is
    treated like Ctrl-C, so cleanups run."""
    import signal
    import sys
    import traceback

    args = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in args
    if strip_debug and debug:
        if argv is None:
            sys.argv[:] = [a for a in sys.argv if a != "--debug"]
        else:
            argv = [a for a in argv if a != "--debug"]

    def _term(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")
    try:
        old = signal.signal(signal.SIGTERM, _term)
    except ValueError:        # not the main thread
        old = None
    prefix = f"{prog}: " if prog else ""
    if not _hook_installed:
        sys.addaudithook(_TrackWrites)
        globals()["_hook_installed"] = True
    try:
        code = main() if (argv is None and strip_debug) else main(argv)
        return int(code or 0)
    except KeyboardInterrupt:
        print(f"{prefix}interrupted", file=sys.stderr, flush=True)
        if debug:
            traceback.print_exc()
        return EXIT_INTERRUPTED
    except SystemExit as err:  # argparse's own exits (usage errors: 2)
        if isinstance(err.code, str):
            print(f"{prefix}error: {err.code}", file=sys.stderr, flush=True)
        return err.code if isinstance(err.code, int) else (0 if err.code is None else 1)
    except BaseException as err:  # noqa: BLE001 - the one top-level handler
        if debug:
            traceback.print_exc()
        hint = "" if debug or isinstance(err, InputError) else " (--debug shows the traceback)"
        print(f"{prefix}error: {OneLine(err)}{_DiskFull(err)}{hint}", file=sys.stderr,
              flush=True)
        return ExitCode(err)
    finally:
        if old is not None:
            signal.signal(signal.SIGTERM, old)
