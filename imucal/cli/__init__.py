"""The ``imucal`` command line: it parses arguments and calls the core and the viewer.

``main`` runs it (exit codes and one-line errors); ``app`` is the typer app every command
module registers on; ``commands`` holds the commands, ``options`` the options they share,
``outputs`` and ``summary`` what they print and check.
"""

from imucal.cli.main import main, view_main

__all__ = ["main", "view_main"]
