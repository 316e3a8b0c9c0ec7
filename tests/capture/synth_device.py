"""A synthetic device for the capture tests: ``imucal synth --stream`` run as a process (the
device a user would plug in), and a free local port for it to send on."""

import os
import socket
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
CLI = [sys.executable, "-c", "import sys; from imucal.cli.main import main; sys.exit(main())"]


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def synth_stream(tmp: Path, stream: str, *extra: str, poses: int = 40, seed: int = 3,
                 speed: str = "50", **popen) -> subprocess.Popen:
    """``imucal synth TMP/s.mat --poses N --seed S --stream STREAM --speed X EXTRA...``."""
    return subprocess.Popen(CLI + ["synth", str(tmp / "s.mat"), "--poses", str(poses),
                                   "--seed", str(seed), "--stream", stream, "--speed", speed,
                                   *extra], env=ENV, **popen)
