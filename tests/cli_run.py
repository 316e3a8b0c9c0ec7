"""The command line run in-process, as the tests of several folders drive it."""

from imucal.cli.main import main


def run(capsys, *args) -> tuple[int, str, str]:
    """``imucal ARGS...``: its exit code, standard output and standard error (never a
    traceback: an error is one line)."""
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return rc, out.out, out.err
