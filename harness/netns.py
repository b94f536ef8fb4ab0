"""A bench of hosts on one machine: network namespaces on a bridge, and everything they run.

``Topology(["learner", "box1"], log_dir)`` makes a hub namespace holding a bridge ``br0``
(10.A.B.1/24) and one namespace per host, each joined to the bridge by a veth pair (host i,
counted from 1, is 10.A.B.(10+i); its side of the pair is ``eth0``). The bridge lives inside
the hub namespace, so the root namespace gains no interface, route or rule. Names carry the
creating pid and a random tag and the subnet is drawn at random, so two benches (or one left
behind by a killed run) never collide; leftovers whose creator is dead are swept at the next
start.

Each host also gets its own ``/dev/shm`` (a directory of the real one, bind-mounted over it
in every process the bench starts there): separate machines share no memory, and Zenoh's
shared-memory transport would otherwise carry bytes between "hosts" that the veth, and so
the faults, never see.

On exit (a failed assertion, Ctrl-C, or interpreter exit as a backstop) every process group
the bench started is stopped, every process still inside one of its namespaces (a launcher's
roles included) is killed, and the namespaces are deleted, which takes the veths with them.
"""

from __future__ import annotations

import atexit
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path

from harness.inside import inside
from harness.processes import Registry, Started

PREFIX = "c2fh"  #: every namespace, veth and /dev/shm directory of a bench starts with this
SHM_ROOT = Path("/dev/shm")
HOST_IFACE = "eth0"  #: a host's side of its veth pair
_LABEL = re.compile(r"[a-z][a-z0-9]{0,9}")


@dataclass(frozen=True)
class Host:
    """One machine of the bench (the hub too)."""

    label: str  #: how tests name it: "hub", "learner", "box1", ...
    netns: str  #: the ``ip netns`` name
    ip: str  #: its address on the bridge
    veth: str  #: its veth's end in the hub namespace ("" for the hub itself)
    shm: Path  #: the directory that is its /dev/shm


def probe() -> str | None:
    """Why this machine cannot run the bench (for ``pytest.skip``), or None when it can."""
    if os.geteuid() != 0:
        return f"network namespaces need root (running as uid {os.geteuid()})"
    for tool in ("ip", "mount"):
        if shutil.which(tool) is None:
            return f"no `{tool}` command (Debian packages iproute2, mount)"
    name = f"{PREFIX}-probe-{os.getpid()}"
    try:
        for argv in (["ip", "netns", "add", name],
                     ["ip", "-n", name, "link", "add", "br0", "type", "bridge"],
                     ["ip", "-n", name, "link", "add", "v0", "type", "veth", "peer", "name", "v1"]):
            result = subprocess.run(argv, capture_output=True, text=True, timeout=30)
            if result.returncode != 0:
                return f"`{' '.join(argv)}` failed: {result.stderr.strip() or result.returncode}"
    finally:
        subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
    return None


def ip(*args: str, timeout: float = 30.0) -> str:
    """Run ``ip ARGS`` (root namespace unless ``-n NAME`` is given); its stdout, or RuntimeError."""
    return _run(["ip", *args], timeout)


def _run(argv: Sequence[str], timeout: float = 30.0, stdin: str | None = None) -> str:
    result = subprocess.run(list(argv), input=stdin, capture_output=True, text=True, timeout=timeout)
    if result.returncode != 0:
        raise RuntimeError(f"`{' '.join(argv)}` failed ({result.returncode}): {result.stderr.strip()}")
    return result.stdout


def namespaces() -> list[str]:
    """Every named network namespace on the machine."""
    return [line.split()[0] for line in ip("netns", "list").splitlines() if line.strip()]


def netns_pids(netns: str) -> list[int]:
    """Every process inside ``netns`` (whatever started it)."""
    result = subprocess.run(["ip", "netns", "pids", netns], capture_output=True, text=True, timeout=30)
    return [int(p) for p in result.stdout.split()] if result.returncode == 0 else []


def sweep_stale() -> list[str]:
    """Delete benches whose creating process is gone (a run killed before it could clean up)."""
    swept = []
    for name in namespaces():
        m = re.fullmatch(rf"{PREFIX}-(\d+)-[0-9a-f]+-\w+", name)
        if m and not _pid_alive(int(m[1])):
            _kill_netns(name)
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
            swept.append(name)
    for path in SHM_ROOT.glob(f"{PREFIX}-*"):
        m = re.match(rf"{PREFIX}-(\d+)-", path.name)
        if m and not _pid_alive(int(m[1])):
            shutil.rmtree(path, ignore_errors=True)
    return swept


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _kill_netns(netns: str, timeout: float = 5.0) -> list[int]:
    """SIGKILL every process in ``netns`` and wait (bounded) until none is left; returns the survivors."""
    deadline = time.monotonic() + timeout
    while True:
        pids = [p for p in netns_pids(netns) if p != os.getpid()]
        if not pids or time.monotonic() > deadline:
            return pids
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.05)


class Topology(AbstractContextManager):
    """A hub namespace with a bridge, N host namespaces on it, and the processes started in them."""

    def __init__(self, hosts: int | Sequence[str], log_dir: str | os.PathLike, *, private_shm: bool = True) -> None:
        labels = [f"h{i}" for i in range(1, hosts + 1)] if isinstance(hosts, int) else list(hosts)
        bad = [x for x in labels if not _LABEL.fullmatch(x) or x == "hub"]
        if bad or len(set(labels)) != len(labels) or not 1 <= len(labels) <= 200:
            raise ValueError(f"host labels must be 1-200 distinct names like 'box1' (not 'hub'): {labels}")
        rng = random.Random(os.urandom(8))
        self.tag = f"{PREFIX}-{os.getpid()}-{rng.getrandbits(16):04x}"
        self.subnet = f"10.{rng.randrange(64, 128)}.{rng.randrange(256)}"
        self.log_dir = Path(log_dir)
        self.private_shm = private_shm
        self.hub = Host("hub", f"{self.tag}-hub", f"{self.subnet}.1", "", SHM_ROOT / f"{self.tag}-hub")
        self.hosts = tuple(
            Host(label, f"{self.tag}-{label}", f"{self.subnet}.{10 + i}", f"v{self.tag[-4:]}{i}",
                 SHM_ROOT / f"{self.tag}-{label}")
            for i, label in enumerate(labels, start=1)
        )
        self.processes = Registry()
        self._made: list[str] = []  #: namespaces created so far, deleted on close
        self._closed = False

    # -- lifecycle --------------------------------------------------------------------

    def __enter__(self) -> Topology:
        try:
            self.create()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def create(self) -> None:
        """Make the namespaces, the bridge and the links (raises RuntimeError naming the failed command)."""
        sweep_stale()
        atexit.register(self.close)
        hub = self.hub.netns
        for host in (self.hub, *self.hosts):
            ip("netns", "add", host.netns)
            self._made.append(host.netns)
            ip("-n", host.netns, "link", "set", "lo", "up")
            if self.private_shm:
                host.shm.mkdir(mode=0o1777, exist_ok=True)
        ip("-n", hub, "link", "add", "br0", "type", "bridge")
        ip("-n", hub, "addr", "add", f"{self.hub.ip}/24", "dev", "br0")
        ip("-n", hub, "link", "set", "br0", "up")
        for host in self.hosts:
            ip("-n", hub, "link", "add", host.veth, "type", "veth", "peer", "name", HOST_IFACE, "netns", host.netns)
            ip("-n", hub, "link", "set", host.veth, "master", "br0")
            ip("-n", hub, "link", "set", host.veth, "up")
            ip("-n", host.netns, "addr", "add", f"{host.ip}/24", "dev", HOST_IFACE)
            ip("-n", host.netns, "link", "set", HOST_IFACE, "up")

    def close(self) -> None:
        """Stop every process, kill whatever is left in the namespaces, delete them. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self.close)
        problems = []
        try:
            self.processes.stop_all(grace_s=3.0)
        except Exception as exc:  # keep cleaning up: the namespaces must go whatever happened
            problems.append(f"stopping processes: {exc}")
        for netns in reversed(self._made):
            left = _kill_netns(netns)
            if left:
                problems.append(f"{netns}: processes {left} survived SIGKILL")
            result = subprocess.run(["ip", "netns", "del", netns], capture_output=True, text=True, timeout=30)
            if result.returncode != 0:
                problems.append(f"ip netns del {netns}: {result.stderr.strip()}")
        for host in (self.hub, *self.hosts):
            shutil.rmtree(host.shm, ignore_errors=True)
        if problems:
            print("harness: cleanup problems: " + "; ".join(problems), file=sys.stderr)

    # -- hosts ------------------------------------------------------------------------

    def host(self, label: str) -> Host:
        """The host (or the hub) called ``label``."""
        for host in (self.hub, *self.hosts):
            if host.label == label:
                return host
        raise KeyError(f"no host {label!r}; hosts are {[h.label for h in self.hosts]}")

    def _host(self, host: Host | str) -> Host:
        return host if isinstance(host, Host) else self.host(host)

    def namespaces(self) -> list[str]:
        """The namespaces of this bench (hub first)."""
        return [self.hub.netns, *(h.netns for h in self.hosts)]

    # -- processes --------------------------------------------------------------------

    def exec_argv(self, host: Host | str, argv: Sequence[str]) -> list[str]:
        """``argv`` as run inside ``host``'s namespace (with its private /dev/shm)."""
        host = self._host(host)
        if not self.private_shm:
            return ["ip", "netns", "exec", host.netns, *argv]
        # `ip netns exec` already gives the command a mount namespace of its own (slave to the
        # root one), so this bind mount is seen by it and its children only.
        script = 'mount --bind "$0" /dev/shm && exec "$@"'
        return ["ip", "netns", "exec", host.netns, "sh", "-c", script, str(host.shm), *argv]

    def spawn(self, host: Host | str, argv: Sequence[str], name: str, *, env: Mapping[str, str] | None = None,
              cwd: str | os.PathLike | None = None) -> Started:
        """Start ``argv`` inside ``host`` in its own process group; output to ``log_dir/<host>-<name>.log``.

        The environment is this process's, updated with ``env``.
        """
        host = self._host(host)
        return self.processes.start(self.exec_argv(host, argv), name=name, host=host.label, log_dir=self.log_dir,
                                    env={**os.environ, **(env or {})}, cwd=cwd)

    def run(self, host: Host | str, argv: Sequence[str], timeout: float = 30.0, stdin: str | None = None) -> str:
        """Run a short command (nft, tc, ...) inside ``host``; its stdout, or RuntimeError."""
        return _run(["ip", "netns", "exec", self._host(host).netns, *argv], timeout, stdin)

    def stop(self, started: Started, timeout: float = 15.0) -> int | None:
        """SIGTERM ``started``'s process group, SIGKILL it after ``timeout``; its exit code."""
        return self.processes.stop(started, timeout)

    def pids(self, host: Host | str) -> list[int]:
        """Every process inside ``host``'s namespace, started by the bench or by what it started."""
        return netns_pids(self._host(host).netns)

    def kill_host(self, host: Host | str) -> None:
        """SIGKILL everything running on ``host`` (a machine that loses power)."""
        host = self._host(host)
        for started in self.processes.all(host.label):
            self.processes.signal(started, signal.SIGKILL)
        _kill_netns(host.netns)
        for started in self.processes.all(host.label):
            try:
                started.popen.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass

    # -- sockets from this process -----------------------------------------------------

    def inside(self, host: Host | str) -> AbstractContextManager[None]:
        """Run a block on the calling thread inside ``host``'s namespace (see :mod:`harness.inside`)."""
        return inside(self._host(host).netns)

    def wait_listening(self, host: Host | str, address: str, port: int, timeout: float = 30.0,
                       process: Started | None = None) -> None:
        """Wait until something inside ``host`` accepts TCP connections on ``address:port``.

        With ``process`` (what should open it), fail as soon as that process has exited.
        """
        import socket

        deadline = time.monotonic() + timeout
        while True:
            try:
                with self.inside(host):
                    socket.create_connection((address, port), timeout=1.0).close()
                return
            except OSError as exc:
                where = f"{address}:{port} in {self._host(host).label}"
                if process is not None and not process.running:
                    raise RuntimeError(f"{process.name} exited ({process.popen.returncode}) before listening on "
                                       f"{where}:\n{process.output()[-2000:]}") from None
                if time.monotonic() > deadline:
                    raise TimeoutError(f"nothing listens on {where}: {exc}") from None
                time.sleep(0.1)

    # -- links ------------------------------------------------------------------------

    def link_counters(self, host: Host | str) -> dict[str, int]:
        """Bytes and packets ``host`` sent and received over its link (read on the hub's side of its veth)."""
        host = self._host(host)
        [link] = json.loads(ip("-n", self.hub.netns, "-s", "-j", "link", "show", "dev", host.veth))
        stats = link["stats64"]
        # the hub side receives what the host sends
        return {"sent_bytes": stats["rx"]["bytes"], "received_bytes": stats["tx"]["bytes"],
                "sent_packets": stats["rx"]["packets"], "received_packets": stats["tx"]["packets"]}

    def __iter__(self) -> Iterator[Host]:
        return iter(self.hosts)

    def __repr__(self) -> str:
        return f"Topology({self.tag}, hub {self.hub.ip}, hosts {[(h.label, h.ip) for h in self.hosts]})"
