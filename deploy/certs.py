"""``c2farm certs``: the keys a run needs beyond loopback, made once on the hub.

Two fabrics, two kinds of key, one directory::

    certs/ca.pem                      the run's certificate authority (every host needs it)
    certs/ca.key                      its private key (0600; keep it on the hub, or offline)
    certs/zenoh/<role>.<instance>.pem a TLS certificate per role process, its common name
    certs/zenoh/<role>.<instance>.key   the identity the router's access control judges (0600)
    certs/curve/replay.key[_secret]   the replay's CURVE key pair (ZeroMQ, learner <-> replay)
    certs/curve/learner.key[_secret]  the learner's CURVE key pair
    certs/curve/clients/learner.key   the public keys the replay lets sample (an allow-list)

Zenoh links are TLS with mutual authentication: every process presents the certificate named
after its role and instance, and the router's access control (``deploy/access_control.py``)
lets each name do only what its role does. The router's certificate also names the hub's
addresses (``--hub``), because a client checks the address it dialled against it.

Running the command again on the same directory keeps the authority and every key already
there and issues only what is missing, so adding an actor host is the same command with more
``--actors`` (or ``--identity``); restart the router afterwards, since Zenoh reads its access
rules once. EC P-256 keys and certificates are made with ``cryptography``, CURVE pairs with
pyzmq.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

#: Common names are ``<role>.<instance>``; the role is the part before the first dot.
SEPARATOR = "."
CA_NAME = "c2farm run CA"
#: Roles of a single-hub run besides the actors (role -> default instance).
HUB_IDENTITIES = (("router", "router"), ("replay", "replay"), ("learner", "learner"), ("dashboard", "dashboard"),
                  ("eval", "eval"), ("demo_source", "demos"))


def identity(role: str, instance: str) -> str:
    """The certificate common name of one role process."""
    return f"{role}{SEPARATOR}{instance}"


def role_of(common_name: str) -> str:
    """``"actor.box3-actor-0"`` -> ``"actor"``."""
    return common_name.split(SEPARATOR, 1)[0]


@dataclass
class CertsPlan:
    """What ``c2farm certs`` makes."""

    directory: Path  #: where the files go (created with 0700)
    hubs: list[str] = field(default_factory=list)  #: addresses or host names clients dial the router by
    actors: int = 2  #: actor certificates actor-0 .. actor-(N-1), with ``instance_prefix`` in front
    instance_prefix: str = ""  #: prepended to the actor instance names, as ``launch.instance_prefix``
    extra: list[str] = field(default_factory=list)  #: more identities, ``role.instance`` (e.g. robot.robot-0)
    days: int = 365  #: validity of every certificate issued now

    def identities(self) -> list[str]:
        names = [identity(role, instance) for role, instance in HUB_IDENTITIES]
        names += [identity("actor", f"{self.instance_prefix}actor-{i}") for i in range(self.actors)]
        return names + [n for n in self.extra if n not in names]


def make_certs(plan: CertsPlan) -> list[Path]:
    """Create what is missing under ``plan.directory``; returns the files written."""
    out = plan.directory
    for sub in (out, out / "zenoh", out / "curve", out / "curve" / "clients"):
        sub.mkdir(parents=True, exist_ok=True)
        os.chmod(sub, 0o700)
    written: list[Path] = []
    ca_key, ca_cert = _authority(out, plan.days, written)
    for name in plan.identities():
        pem = out / "zenoh" / f"{name}.pem"
        if pem.exists():
            continue
        hosts = ["localhost", "127.0.0.1", *plan.hubs] if role_of(name) == "router" else []
        key = _new_key()
        _write(out / "zenoh" / f"{name}.key", _key_pem(key), private=True, written=written)
        _write(pem, _issue(ca_key, ca_cert, key, name, hosts, plan.days), written=written)
    written += _curve_pairs(out / "curve")
    return written


def certificate_names(directory: Path) -> list[str]:
    """Common names of the Zenoh certificates in ``directory/zenoh`` that our authority signed."""
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    ca = x509.load_pem_x509_certificate((directory / "ca.pem").read_bytes())
    names = []
    for pem in sorted((directory / "zenoh").glob("*.pem")):
        cert = x509.load_pem_x509_certificate(pem.read_bytes())
        if cert.issuer != ca.subject:
            continue
        names += [a.value for a in cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)]
    return names


def check_certificate(directory: Path, name: str, now: datetime.datetime | None = None) -> None:
    """ValueError in one line unless ``directory`` holds a usable certificate and key for ``name``.

    Zenoh would refuse such a link too, but later and with a message that does not say which
    file is wrong; this says it before the process opens anything.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

    ca_path, pem, key = directory / "ca.pem", directory / "zenoh" / f"{name}.pem", directory / "zenoh" / f"{name}.key"
    for path in (ca_path, pem, key):
        if not path.is_file():
            raise ValueError(f"{path}: missing (make it with `c2farm certs {directory} --identity {name}`)")
    if key.stat().st_mode & 0o077:
        raise ValueError(f"{key}: readable by others (mode {key.stat().st_mode & 0o777:o}); chmod 600 it")
    try:
        ca = x509.load_pem_x509_certificate(ca_path.read_bytes())
        cert = x509.load_pem_x509_certificate(pem.read_bytes())
    except ValueError as exc:
        raise ValueError(f"{pem}: not a PEM certificate ({exc})") from None
    now = now or datetime.datetime.now(datetime.timezone.utc)
    if not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc:
        raise ValueError(f"{pem}: expired or not yet valid (valid {cert.not_valid_before_utc:%Y-%m-%d} to "
                         f"{cert.not_valid_after_utc:%Y-%m-%d})")
    try:
        if cert.issuer != ca.subject:
            raise ValueError("issuer differs")
        ca.public_key().verify(cert.signature, cert.tbs_certificate_bytes, ec.ECDSA(cert.signature_hash_algorithm))
    except Exception:  # noqa: BLE001 - any failure means the same to the user
        raise ValueError(f"{pem}: not signed by {ca_path} (a certificate of another run's authority?)") from None


# -- internals ---------------------------------------------------------------------------


def _authority(out: Path, days: int, written: list[Path]):
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    key_path, cert_path = out / "ca.key", out / "ca.pem"
    if key_path.exists() and cert_path.exists():
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        return key, x509.load_pem_x509_certificate(cert_path.read_bytes())
    key = _new_key()
    cert = _certificate(_name(CA_NAME), _name(CA_NAME), key.public_key(), key, days, ca=True, hosts=())
    _write(key_path, _key_pem(key), private=True, written=written)
    _write(cert_path, _cert_pem(cert), written=written)
    return key, cert


def _issue(ca_key, ca_cert, key, name: str, hosts: Sequence[str], days: int) -> bytes:
    return _cert_pem(_certificate(_name(name), ca_cert.subject, key.public_key(), ca_key, days, ca=False, hosts=hosts))


def _certificate(subject, issuer, public_key, signing_key, days: int, ca: bool, hosts: Iterable[str]):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.x509.oid import ExtendedKeyUsageOID

    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer).public_key(public_key)
               .serial_number(x509.random_serial_number())
               .not_valid_before(now - datetime.timedelta(minutes=5))
               .not_valid_after(now + datetime.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True))
    if ca:
        builder = builder.add_extension(x509.KeyUsage(True, False, False, False, False, True, True, False, False), True)
    else:
        builder = builder.add_extension(
            x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
        names = [_san(h) for h in hosts]
        if names:
            builder = builder.add_extension(x509.SubjectAlternativeName(names), critical=False)
    return builder.sign(signing_key, hashes.SHA256())


def _san(host: str):
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _curve_pairs(directory: Path) -> list[Path]:
    import zmq.auth

    written = []
    for name in ("replay", "learner"):
        if not (directory / f"{name}.key_secret").exists():
            public, secret = zmq.auth.create_certificates(str(directory), name)
            os.chmod(secret, 0o600)
            written += [Path(public), Path(secret)]
    allowed = directory / "clients" / "learner.key"
    if not allowed.exists():
        allowed.write_bytes((directory / "learner.key").read_bytes())
        written.append(allowed)
    return written


def _name(common_name: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _new_key():
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)


def _write(path: Path, data: bytes, private: bool = False, written: list[Path] | None = None) -> None:
    """Write ``data``; a private file is created 0600 (never world-readable, not even for a moment)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC
    fd = os.open(path, flags, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    if written is not None:
        written.append(path)
