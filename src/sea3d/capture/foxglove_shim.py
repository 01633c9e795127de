"""Accept Foxglove clients that offer only the old ``foxglove.websocket.v1`` subprotocol.

foxglove-sdk (0.30) answers only ``foxglove.sdk.v1`` (and ``foxglove.sdk.v1.1``) in the
WebSocket handshake and rejects a client offering only the protocol's former name with HTTP 400;
nothing in its Python API changes that (the names are compiled into its Rust server). The wire
protocol is the same one renamed (ws-protocol's spec: the JSON ops and binary opcodes that the
old name covers are unchanged), so Lichtblick releases from before their ``foxglove.sdk.v1``
support, and other clients of the old name, work once the handshake agrees on a name.

:class:`SubprotocolShim` listens on the public address and forwards each TCP connection to the
SDK's server on a loopback port. In the client's HTTP upgrade request it rewrites a
``Sec-WebSocket-Protocol`` offer of only ``foxglove.websocket.v1`` to ``foxglove.sdk.v1``, and in
the server's answer it rewrites the chosen name back, so each side sees the name it speaks.
Every other byte passes through unchanged; clients offering the new name are not touched.
"""

from __future__ import annotations

import errno
import logging
import re
import socket
import threading

from sea3d.errors import CaptureError

__all__ = ["NEW_SUBPROTOCOL", "OLD_SUBPROTOCOL", "SubprotocolShim", "rewrite_offer"]

_log = logging.getLogger(__name__)

OLD_SUBPROTOCOL = "foxglove.websocket.v1"
NEW_SUBPROTOCOL = "foxglove.sdk.v1"
_HEADER = re.compile(rb"^(sec-websocket-protocol:[ \t]*)([^\r\n]*)\r\n", re.I | re.M)
_MAX_HEADER_BYTES = 64 * 1024


def rewrite_offer(request: bytes) -> tuple[bytes, bool]:
    """The client's upgrade request with an old-name-only offer renamed, and whether it was.

    Args:
        request: the HTTP request head, up to and including the blank line.

    Returns:
        ``(request, renamed)``: unchanged (False) unless the client offers
        ``foxglove.websocket.v1`` and not ``foxglove.sdk.v1``.
    """
    m = _HEADER.search(request)
    if m is None:
        return request, False
    offered = [p.strip() for p in m.group(2).decode("latin-1").split(",")]
    if OLD_SUBPROTOCOL not in offered or any(p.startswith(NEW_SUBPROTOCOL) for p in offered):
        return request, False
    renamed = ", ".join(NEW_SUBPROTOCOL if p == OLD_SUBPROTOCOL else p for p in offered)
    out = request[: m.start(2)] + renamed.encode("latin-1") + request[m.end(2):]
    return out, True


def _rewrite_answer(response: bytes) -> bytes:
    m = _HEADER.search(response)
    if m is None or m.group(2).strip() != NEW_SUBPROTOCOL.encode():
        return response
    return response[: m.start(2)] + OLD_SUBPROTOCOL.encode() + response[m.end(2):]


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """Read up to the end of an HTTP head; returns ``(head, bytes after it)``."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(4096)
        if not chunk:
            break
        buf += chunk
        if len(buf) > _MAX_HEADER_BYTES:
            break
    end = buf.find(b"\r\n\r\n")
    if end < 0:
        return buf, b""
    return buf[: end + 4], buf[end + 4:]


def _pump(src: socket.socket, dst: socket.socket) -> None:
    try:
        while True:
            data = src.recv(65536)
            if not data:
                break
            dst.sendall(data)
    except OSError:
        pass
    finally:
        for s in (dst, src):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


class SubprotocolShim:
    """A TCP front for the SDK's WebSocket server that also accepts the old subprotocol name.

    Args:
        host, port: the public address (port 0: any free port; see :attr:`port`).
        target_port: the SDK server's port on 127.0.0.1; None: not known yet, call
            :meth:`start` once the server runs. The address is bound (and named when taken)
            at once, but connections are accepted only once the target is known: a client
            that comes while the server starts waits in the listen queue instead of being
            forwarded to no server and dropped mid-handshake.

    Raises:
        CaptureError: the public address cannot be bound (a port in use is named).
    """

    def __init__(self, host: str, port: int, target_port: int | None = None) -> None:
        self.target = ("127.0.0.1", 0)
        self.renamed = 0  # connections whose handshake was renamed
        try:
            family = socket.AF_INET6 if ":" in host else socket.AF_INET
            self._sock = socket.create_server((host, port), family=family)
        except OSError as err:
            in_use = " (another program, or another sea3d, holds it)" if (
                err.errno == errno.EADDRINUSE) else ""
            raise CaptureError(f"cannot serve Foxglove on {host}:{port}: "
                               f"{err.strerror or err}{in_use}") from err
        self._sock.settimeout(0.2)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="foxglove-shim", daemon=True)
        if target_port is not None:
            self.start(target_port)

    def start(self, target_port: int) -> None:
        """Forward to the SDK server on 127.0.0.1:``target_port`` and start accepting."""
        self.target = ("127.0.0.1", int(target_port))
        self._thread.start()

    @property
    def port(self) -> int:
        """The public TCP port."""
        return int(self._sock.getsockname()[1])

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            threading.Thread(target=self._serve, args=(client,), daemon=True,
                             name="foxglove-shim-conn").start()

    def _serve(self, client: socket.socket) -> None:
        try:
            client.settimeout(10.0)
            head, rest = _read_head(client)
            head, renamed = rewrite_offer(head)
            upstream = socket.create_connection(self.target, timeout=10.0)
            upstream.sendall(head + rest)
            if renamed:
                self.renamed += 1
                answer, more = _read_head(upstream)
                client.sendall(_rewrite_answer(answer) + more)
                _log.debug("Foxglove client offering only %s accepted", OLD_SUBPROTOCOL)
            client.settimeout(None)
            upstream.settimeout(None)
        except OSError as err:
            _log.debug("Foxglove connection dropped during the handshake: %s", err)
            client.close()
            return
        threading.Thread(target=_pump, args=(upstream, client), daemon=True).start()
        _pump(client, upstream)

    def close(self) -> None:
        """Stop accepting (open connections end with the server). Safe to call twice."""
        self._stop.set()
        try:
            self._sock.close()
        except OSError:
            pass
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
