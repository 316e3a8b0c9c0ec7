"""The ``imucal`` typer app itself: its name, help and context, and the root's ``--version``.

Every command module registers its commands on :data:`app` as it is imported
(``@app.command()``); :mod:`imucal.cli.main` imports them all. Defined here, apart from every
command, so that each command module imports the app without importing the others: imports
run one way (main -> command modules -> app). Only typer at module level (``imucal --help``
stays fast).
"""

from __future__ import annotations

from typing import Annotated

import typer

app = typer.Typer(
    name="imucal",
    help="Calibrate an IMU's accelerometer and gyroscope from an ordinary recording "
         "(still poses with turns between them).",
    add_completion=True,  # --install-completion, --show-completion (typer's)
    no_args_is_help=True,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)


def print_version(ctx: typer.Context, value: bool) -> None:
    """``--version``: the program's name and :data:`imucal.__version__` (the package's)."""
    if value and not ctx.resilient_parsing:
        import imucal

        print(f"{ctx.find_root().info_name or 'imucal'} {imucal.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=print_version, is_eager=True,
                                          help="Show the version and exit.")] = False,
) -> None:
    """Calibrate an IMU's accelerometer and gyroscope from an ordinary recording.

    Exit codes: 0 success, 1 a problem with the input, files or settings, 2 a usage error,
    3 an internal error, 130 interrupted.
    """
