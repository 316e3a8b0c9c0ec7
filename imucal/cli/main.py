"""The ``imucal`` command: calibrate, apply, synth, view.

Only the standard library and typer are imported at module level so that ``imucal --help``
stays fast; numpy, scipy, polars and the core modules are imported inside the commands, and
rerun only by ``--rrd`` and ``view``.

Exit codes: 0 success; 1 a problem with the user's input, files or settings (one line on
stderr, ``imucal: error: ...``); 2 a usage error (unknown option, bad option value); 3 an
internal error (a bug in imucal, one line; ``IMUCAL_DEBUG=1`` shows the traceback); 130
interrupted (Ctrl-C, or a polite kill: SIGTERM, SIGHUP).
"""


from __future__ import annotations

import contextlib
import functools
import os
import sys

import typer

# Each command module registers its commands on app as it is imported; --help lists them in
# that order: commands.py's first (capture.py imports it for calibrate), then the others'.
from imucal.cli import capture as _capture  # noqa: F401  (registers capture and replay on app)
from imucal.cli import commands as _commands  # noqa: F401  (calibrate, apply, synth, view)
from imucal.cli import fleet as _fleet  # noqa: F401  (registers batch and store on app)
from imucal.cli import inuse as _inuse  # noqa: F401  (registers check and refresh on app)
from imucal.cli import tools  # noqa: F401  (registers export and noise on app)
from imucal.cli.app import app
from imucal.errors import ImucalError

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


# --- entry point -------------------------------------------------------------------------------


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _err(message: str, prog: str = "imucal") -> None:
    try:
        sys.stderr.write(f"{prog}: {_one_line(message)}\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def _show_warning(message, category, filename, lineno, file=None, line=None,
                  prog: str = "imucal") -> None:
    """Python warnings from the libraries, as one line each."""
    _err(f"warning: {category.__name__}: {message}", prog)


def _on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _polite_kills() -> list[int]:
    """The signals that unwind like Ctrl-C: SIGTERM, and SIGHUP (the terminal closed, an ssh
    session dropped) where the platform has it; by default both would end the process on the
    spot, leaving its temporaries and lock files beside the outputs (issue 27)."""
    import signal

    return [getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n)]


def _unreadable_is_the_readers(cli) -> None:
    """click refuses an unreadable path argument as a usage error (exit 2); a file without
    read permission is the user's data, not their usage: the reader reports it, exit 1 with
    the file named (README's contract; issue 27)."""
    for cmd in [cli, *getattr(cli, "commands", {}).values()]:
        for sub in [cmd, *getattr(cmd, "commands", {}).values()]:
            for param in sub.params:
                if getattr(param.type, "readable", False) is True:  # click's (typer's) Path
                    param.type.readable = False


def main(argv: list[str] | None = None, *, command: str | None = None,
         prog: str = "imucal") -> int:
    """Run the command line; return the exit code (never a traceback for the user).

    ``command`` runs one subcommand directly under the name ``prog`` (``imucal-view`` is
    ``imucal view``). The process-wide hooks a run installs (the SIGTERM handler, the one-line
    warnings) are put back when it returns, so a caller in the same process (a test, a
    notebook, a batch) keeps its own."""
    import signal
    import warnings

    old_handlers = {sig: signal.getsignal(sig) for sig in _polite_kills()}
    old_show = warnings.showwarning
    try:
        return _main(argv, command=command, prog=prog)
    finally:
        warnings.showwarning = old_show
        for sig, handler in old_handlers.items():
            with contextlib.suppress(ValueError, TypeError):  # not the main thread: never set
                signal.signal(sig, handler)


def _setup_process() -> None:
    """What a command-line run of imucal sets for its process before any work."""
    # The fits work on small matrices: a second BLAS thread only spins (measured in bench/:
    # 1.5 s CPU for 0.8 s wall on a 60-minute session). Set before numpy is first imported;
    # a user's own setting wins.
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    # A polite kill (SIGTERM, SIGHUP) unwinds like Ctrl-C, so a write in progress removes its
    # temporary and lock files instead of leaving them beside the output.
    import signal

    for sig in _polite_kills():
        with contextlib.suppress(ValueError):  # not the main thread (tests): keep the default
            signal.signal(sig, _on_sigterm)
    # A terminal or PYTHONIOENCODING that cannot show a character (the summary's file names,
    # a unit) gets an escape for it, not a UnicodeEncodeError after the files were written.
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError, OSError):
            stream.reconfigure(errors="backslashreplace")


def _main(argv: list[str] | None, *, command: str | None, prog: str) -> int:
    """Run the command line; every outcome becomes an exit code and at most one line."""
    import warnings

    args = sys.argv[1:] if argv is None else list(argv)
    _setup_process()
    debug = os.environ.get("IMUCAL_DEBUG", "") not in ("", "0")
    if not debug:
        warnings.showwarning = functools.partial(_show_warning, prog=prog)
    err = functools.partial(_err, prog=prog)
    try:
        cli = _plain_usage(typer.main.get_command(app))
        if command is not None:
            cli = _as_program(cli, command)
        _unreadable_is_the_readers(cli)
        rv = cli.main(args, prog_name=prog, standalone_mode=False)
        if rv == EXIT_INTERRUPTED:
            err("interrupted")
        return rv if isinstance(rv, int) else EXIT_OK
    except ImucalError as e:
        err(f"error: {e}")
        return EXIT_ERROR
    except typer.Abort:
        err("aborted")
        return EXIT_ERROR
    except typer.TyperException as e:  # click's usage errors (exit 2) and the like
        show = getattr(e, "show", None)
        if show is not None:
            show()
        else:
            err(f"error: {e}")
        return int(getattr(e, "exit_code", EXIT_USAGE))
    except KeyboardInterrupt:
        err("interrupted")
        return EXIT_INTERRUPTED
    except SystemExit as e:  # typer's --show-completion, --install-completion, completion
        if isinstance(e.code, str):
            err(e.code)
        return e.code if isinstance(e.code, int) else EXIT_OK if e.code is None else EXIT_ERROR
    except BrokenPipeError:
        # The reader of stdout went away (e.g. `imucal ... | head`): stop quietly.
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115
        return EXIT_ERROR
    except MemoryError:
        err("error: not enough memory")
        return EXIT_ERROR
    except OSError as e:
        if debug:
            raise
        where = e.filename if e.filename is not None else ""
        reason = e.strerror or e.__class__.__name__
        err(f"error: {where}: {reason}" if where else f"error: {reason}")
        return EXIT_ERROR
    except Exception as e:
        if debug:
            raise
        err(f"internal error: {e.__class__.__name__}: {e} (a bug in imucal; run with "
             "IMUCAL_DEBUG=1 for the traceback)")
        return EXIT_INTERNAL


class _PlainArgument(typer.core.TyperArgument):
    """An argument written in usage lines as its bare metavar: ``imucal calibrate [OPTIONS]
    SESSION`` (typer 0.28 writes a required argument as ``{SESSION}``, which reads as a literal
    to type, braces and all)."""

    def get_usage_pieces(self, ctx: typer.Context) -> list[str]:
        piece = self.make_metavar(ctx, usage=True)  # an optional one keeps its [ ]
        return [piece[1:-1] if piece.startswith("{") and piece.endswith("}") else piece]


def _plain_usage(cli):
    """Every argument of ``cli`` and of its subcommands as a :class:`_PlainArgument`."""
    for param in cli.params:
        if type(param) is typer.core.TyperArgument:
            param.__class__ = _PlainArgument  # the same fields; only the usage piece differs
    for sub in getattr(cli, "commands", {}).values():
        _plain_usage(sub)
    return cli


def _as_program(group: typer.core.TyperGroup, command: str) -> typer.core.TyperCommand:
    """One subcommand as a program of its own (``imucal-view`` is ``imucal view``), with the
    root's ``--version`` and typer's ``--install-completion``/``--show-completion`` (which a
    subcommand does not get): built afresh on each run, so ``imucal view`` keeps its own."""
    import copy

    cli = group.commands[command]
    for param in group.params:
        if param.name in ("version", "install_completion", "show_completion"):
            param = copy.copy(param)
            param.expose_value = False  # handled by its callback, never passed to the command
            cli.params.append(param)
    return cli


def view_main(argv: list[str] | None = None) -> None:
    """Entry point of the ``imucal-view`` script: ``imucal view`` under its own name, so both
    take the same options (two-file sessions, units, every setting) and report errors alike."""
    sys.exit(main(argv, command="view", prog="imucal-view"))


if __name__ == "__main__":
    sys.exit(main())
