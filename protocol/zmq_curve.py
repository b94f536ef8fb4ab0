"""CURVE on the learner <-> replay ZeroMQ link: key files, config checks, socket set-up, handshake events.

Key files are those of ``zmq.auth.create_certificates(dir, name)``: ``NAME.key`` holds the public
key, ``NAME.key_secret`` the public and the secret key (z85 text). The replay holds its own
``.key_secret`` and a directory of the learners' public ``.key`` files it allows; a learner holds
its own ``.key_secret`` and the replay's public ``.key``. A file holding a secret key must be
private (no access for group or others: ``chmod 600``). With CURVE on, only holders of an
allowed key complete the handshake; everything on the link is encrypted, and every message the
replay receives names the sender's public key (its ``User-Id`` property).

Both roles use this module (it lives in ``protocol/`` for that reason). The config checks run
in each section's ``__post_init__`` and import pyzmq only when a key is set.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

#: ZAP domain of the replay's sample service (the authenticator's keys live under it).
ZAP_DOMAIN = "c2farm-replay"


class CurveKeyError(ValueError):
    """A key file that is missing, unreadable, malformed, or not private enough; one line."""


# ---------------------------------------------------------------------------- key files
def _z85_key(text: bytes | None, what: str, path: str) -> bytes:
    from zmq.utils import z85

    if not text:
        raise CurveKeyError(f"{path} holds no {what} (not a zmq.auth certificate file?)")
    try:
        if len(text) != 40 or len(z85.decode(text)) != 32:
            raise ValueError
    except Exception:
        raise CurveKeyError(f"{path}: malformed {what} (expected 40 z85 characters)") from None
    return text


def _load(path: str) -> tuple[bytes | None, bytes | None]:
    import zmq.auth

    p = Path(path)
    if not p.is_file():
        raise CurveKeyError(f"{path}: {'not a file' if p.exists() else 'no such file'}")
    try:
        return zmq.auth.load_certificate(p)
    except OSError as exc:
        raise CurveKeyError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except ValueError:
        raise CurveKeyError(f"{path} holds no public key (not a zmq.auth certificate file?)") from None


def load_keypair(path: str) -> tuple[bytes, bytes]:
    """``(public, secret)`` z85 keys of a ``NAME.key_secret`` file that only its owner can read."""
    public, secret = _load(path)
    public = _z85_key(public, "public key", path)
    secret = _z85_key(secret, "secret key (use NAME.key_secret, not NAME.key)", path)
    mode = os.stat(path).st_mode & 0o777
    if os.name == "posix" and mode & 0o077:
        raise CurveKeyError(f"{path} holds a secret key but others may access it (mode {mode:04o}): "
                            f"chmod 600 {path}")
    return public, secret


def load_public(path: str) -> bytes:
    """The z85 public key of a ``NAME.key`` file; a file that also holds a secret key is refused
    (a peer's secret has no business on this machine)."""
    public, secret = _load(path)
    if secret:
        raise CurveKeyError(f"{path} holds a secret key: give the peer's public NAME.key file instead")
    return _z85_key(public, "public key", path)


def allowed_clients(directory: str) -> dict[bytes, str]:
    """Public key (z85) -> name (file stem) of every ``*.key`` file in ``directory``; at least one."""
    d = Path(directory)
    if not d.is_dir():
        raise CurveKeyError(f"{directory}: {'not a directory' if d.exists() else 'no such directory'}")
    try:
        files = sorted(f for f in d.glob("*.key") if f.is_file())
    except OSError as exc:
        raise CurveKeyError(f"{directory}: cannot list it ({exc.strerror or exc})") from None
    if not files:
        raise CurveKeyError(f"{directory} holds no public NAME.key file: no client could connect")
    return {load_public(str(f)): f.stem for f in files}


# ---------------------------------------------------------------------------- config checks
def check_pair(cfg: Any, certificate: str, peer: str, peer_kind: str) -> None:
    """Config check: ``certificate`` (own ``.key_secret``) and ``peer`` (``peer_kind``: "file" of a
    public key, or "directory" of them) are both set or both empty, and load.

    Raises ``ValueError("<field> ...")`` in one line, as ``protocol.config_checks`` does."""
    cert, other = str(getattr(cfg, certificate) or ""), str(getattr(cfg, peer) or "")
    if not cert and not other:
        return
    if not cert or not other:
        empty, given = (certificate, peer) if not cert else (peer, certificate)
        raise ValueError(f"{empty} must be set too when {given} is (CURVE needs both; leave both empty for "
                         f"plaintext)")
    for name, path, load in ((certificate, cert, load_keypair),
                             (peer, other, allowed_clients if peer_kind == "directory" else load_public)):
        try:
            load(path)
        except CurveKeyError as exc:
            raise ValueError(f"{name} must be a readable CURVE key {peer_kind if name == peer else 'file'} "
                             f"({exc})") from None


# ---------------------------------------------------------------------------- sockets
def client_socket(sock, certificate: str, server_key: str) -> None:
    """Make a (not yet connected) client socket use CURVE with these key files."""
    sock.curve_publickey, sock.curve_secretkey = load_keypair(certificate)
    sock.curve_serverkey = load_public(server_key)


# ---------------------------------------------------------------------------- handshake events
def handshake_events() -> int:
    """The monitor event mask both ends watch: handshake failures and successes (nothing chattier)."""
    import zmq

    return (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
            | zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_SUCCEEDED)


def drain_events(monitor, limit: int = 4096) -> list[tuple[int, int]]:
    """``(event, value)`` of every monitor event waiting on ``monitor`` (never blocks)."""
    import zmq
    from zmq.utils.monitor import parse_monitor_message

    out = []
    for _ in range(limit):
        try:
            msg = parse_monitor_message(monitor.recv_multipart(zmq.NOBLOCK))
        except zmq.Again:
            break
        out.append((int(msg["event"]), int(msg["value"])))
    return out


def describe_failure(event: int, value: int) -> tuple[str, str]:
    """``(reason, text)`` of a handshake-failure event: reason ``auth`` or ``handshake``."""
    import zmq

    if event == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
        return "auth", f"CURVE key refused (ZAP {value}): not among the allowed client keys"
    if event == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
        text = {
            zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
                "security mechanism mismatch (one end plaintext, the other CURVE)",
            zmq.PROTOCOL_ERROR_ZMTP_CRYPTOGRAPHIC:
                "cryptographic error: the client encrypted for another server key",
        }.get(value, f"ZMTP protocol error 0x{value:08x}")
        return "handshake", text
    name = errno.errorcode.get(value, str(value))
    return "handshake", (f"connection closed during the handshake ({name}): a wrong server key, "
                         f"or one end plaintext and the other CURVE?")
