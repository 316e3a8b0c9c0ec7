"""An existing Dask scheduler (``imucal batch --scheduler``): its address checked as the user
gives it, and a prompt look at what answers there before a client waits on it (issue 27).

Dask's client, pointed at a closed port, retries for its whole timeout and then says only
"OSError"; pointed at a server of another protocol it reads that server's first bytes as a
message length and asks for gigabytes ("not enough memory"). :func:`probe` connects once, with
a short timeout, and reads the greeting a Dask server sends to every new connection (its
handshake, framed as Dask's TCP comm frames every message: a 64-bit total length, then a 64-bit
frame count), so that each of these is one line saying what is there.

Standard library only: the address is checked before Dask is imported.
"""

from __future__ import annotations

import socket
import struct
import time

from imucal.errors import ImucalError

# Connecting and the greeting: a scheduler accepts and greets at once, on loopback or across a
# network; 5 s is ample for that and short for a user waiting on a wrong address.
PROBE_SECONDS = 5.0
# What Client then gets to register with a scheduler that greeted (a busy one may be slow).
CLIENT_TIMEOUT = "20s"
SCHEMES = ("tcp", "tls", "ws", "wss", "ucx", "inproc")  # distributed's comm backends
_GREETING = struct.Struct("=QQ")  # Dask's frame header: total bytes, number of frames
_GREETING_MAX = 1 << 20  # a handshake is a few hundred bytes; a length past 1 MiB is not one


def split_address(text: str) -> tuple[str, str, int | None]:
    """``text`` as (scheme, host, port): ``tcp://HOST:PORT`` (a bare ``HOST:PORT`` is tcp, as
    Dask reads it; ``[::1]:PORT`` for IPv6). A ValueError says what was expected."""
    expected = "expected tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786"
    scheme, sep, rest = text.partition("://")
    if not sep:
        scheme, rest = "tcp", text
    if scheme not in SCHEMES:
        raise ValueError(f"{text!r}: unknown scheme {scheme!r} (Dask knows "
                         f"{', '.join(SCHEMES)}); {expected}")
    if scheme in ("ucx", "inproc"):  # addresses of their own forms: Dask checks them
        return scheme, rest, None
    host, colon, port = rest.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not colon or not host or "/" in rest:
        raise ValueError(f"{text!r} has no HOST:PORT; {expected}")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"{text!r}: port {port!r} is not a number 1-65535; {expected}")
    return scheme, host, int(port)


def probe(address: str, timeout: float | None = None) -> None:
    """Raise an ImucalError unless a Dask server answers at ``address`` (tcp only: another
    scheme is left to Dask) within ``timeout`` seconds (:data:`PROBE_SECONDS`)."""
    timeout = PROBE_SECONDS if timeout is None else timeout
    scheme, host, port = split_address(address)
    if scheme != "tcp":
        return
    where = f"tcp://{host}:{port}" if ":" not in host else f"tcp://[{host}]:{port}"
    no = f"no Dask scheduler at {where}"
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except ConnectionRefusedError:
        raise ImucalError(f"{no}: connection refused (nothing listens on that port)",
                          field="--scheduler") from None
    except TimeoutError:
        raise ImucalError(f"{no}: no answer to a connection within {timeout:g} s",
                          field="--scheduler") from None
    except OSError as e:  # an unknown host name, an unreachable network
        raise ImucalError(f"{no}: {e.strerror or e}", field="--scheduler") from None
    greeting, closed = b"", False
    with sock:
        while len(greeting) < _GREETING.size:
            sock.settimeout(max(deadline - time.monotonic(), 0.001))
            try:
                chunk = sock.recv(_GREETING.size - len(greeting))
            except TimeoutError:
                break
            except OSError:  # reset by the peer
                closed = True
                break
            if not chunk:
                closed = True
                break
            greeting += chunk
    said = f"; its first bytes: {greeting[:_GREETING.size]!r}" if greeting else ""
    if len(greeting) == _GREETING.size:
        total, frames = _GREETING.unpack(greeting)
        if _GREETING.size <= total <= _GREETING_MAX and 1 <= frames <= 64:
            return
        raise ImucalError(f"{where} is a server, but not a Dask scheduler (its greeting is "
                          f"not Dask's){said}", field="--scheduler")
    if closed:
        raise ImucalError(f"{where} is a server, but not a Dask scheduler: it closed the "
                          f"connection without a Dask greeting{said}", field="--scheduler")
    raise ImucalError(f"{where} is a server, but not a Dask scheduler: it sent "
                      f"{'too little' if greeting else 'nothing'} within {timeout:g} s of the "
                      f"connection (a Dask scheduler greets a client at once){said}",
                      field="--scheduler")


__all__ = ["CLIENT_TIMEOUT", "PROBE_SECONDS", "probe", "split_address"]
