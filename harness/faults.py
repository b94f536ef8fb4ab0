"""Faults on one host's link, made where a network would make them: between the host and the hub.

Every fault acts on the hub's end of the host's veth, so the host's own stack behaves as a
machine's would (its sockets see silence, never an error the fault invented):

- ``loss``: an nftables ``netdev`` rule ``numgen random mod 10000 < P drop`` on that veth's
  ingress (what the host sends) and egress (what it receives). Not an ``output``-hook rule:
  a drop there returns EPERM to the sending socket, which no lossy network does.
- ``bandwidth``: a ``tbf`` qdisc on each end (tbf shapes only what leaves a device, and the
  host's upload leaves by its own ``eth0``).
- ``cut`` / ``restore``: the hub's end set down / up: a pulled cable. The host sees its carrier
  go; packets vanish both ways; nothing sends a RST, so TCP connections survive a short cut
  and retransmit when it heals (a drop-all rule would do the same to TCP, but would leave the
  host's carrier up, which no unplugged machine has).
- ``vanish``: the host's processes SIGKILLed and its link deleted: a machine gone for good.
- ``clear``: back to a clean, up link.
"""

from __future__ import annotations

from harness.netns import HOST_IFACE, Host, Topology

TABLE = "c2fh_faults"  #: the nftables table (family netdev) in the hub namespace


class Faults:
    """Faults on the links of one :class:`Topology`."""

    def __init__(self, topology: Topology) -> None:
        self.topology = topology
        self._chained: set[str] = set()  #: hosts whose netdev chains exist
        self._gone: set[str] = set()  #: hosts that vanished

    def _host(self, host: Host | str) -> Host:
        host = host if isinstance(host, Host) else self.topology.host(host)
        if host.label in self._gone:
            raise ValueError(f"{host.label} vanished; it has no link any more")
        if not host.veth:
            raise ValueError("faults act on a host's link; the hub has none of its own")
        return host

    def _nft(self, script: str) -> None:
        self.topology.run(self.topology.hub, ["nft", "-f", "-"], stdin=script)

    def _chains(self, host: Host) -> tuple[str, str]:
        """The host's ingress and egress chains on its veth, made on first use."""
        inbound, outbound = f"{host.label}_in", f"{host.label}_out"
        if host.label not in self._chained:
            self._nft(
                f"table netdev {TABLE} {{\n"
                f'  chain {inbound} {{ type filter hook ingress device "{host.veth}" priority 0; }}\n'
                f'  chain {outbound} {{ type filter hook egress device "{host.veth}" priority 0; }}\n'
                "}\n"
            )
            self._chained.add(host.label)
        return inbound, outbound

    def loss(self, host: Host | str, percent: float) -> None:
        """Drop ``percent`` % of the packets in each direction, at random (replaces an earlier loss)."""
        if not 0 <= percent <= 100:
            raise ValueError(f"percent must be in [0, 100], got {percent}")
        host = self._host(host)
        inbound, outbound = self._chains(host)
        lines = [f"flush chain netdev {TABLE} {inbound}", f"flush chain netdev {TABLE} {outbound}"]
        threshold = round(percent * 100)  # in 1/10000: 0.01 % steps
        if threshold:
            lines += [f"add rule netdev {TABLE} {chain} numgen random mod 10000 < {threshold} drop"
                      for chain in (inbound, outbound)]
        self._nft("\n".join(lines) + "\n")

    def bandwidth(self, host: Host | str, rate: str, burst: str = "32kb", latency_ms: int = 200) -> None:
        """Shape the link to ``rate`` (tc's units: "2mbit", "500kbit") each way, queueing at most ``latency_ms``."""
        host = self._host(host)
        shape = ["root", "tbf", "rate", rate, "burst", burst, "latency", f"{latency_ms}ms"]
        self.topology.run(self.topology.hub, ["tc", "qdisc", "replace", "dev", host.veth, *shape])
        self.topology.run(host, ["tc", "qdisc", "replace", "dev", HOST_IFACE, *shape])

    def cut(self, host: Host | str) -> None:
        """Pull the host's cable: its link goes down, packets vanish both ways, no RST anywhere."""
        host = self._host(host)
        self.topology.run(self.topology.hub, ["ip", "link", "set", "dev", host.veth, "down"])

    def restore(self, host: Host | str) -> None:
        """Plug the cable back in (after :meth:`cut`)."""
        host = self._host(host)
        self.topology.run(self.topology.hub, ["ip", "link", "set", "dev", host.veth, "up"])

    def vanish(self, host: Host | str) -> None:
        """The machine is gone for good: every process on it killed, its link deleted."""
        host = self._host(host)
        self.topology.kill_host(host)
        self.topology.run(self.topology.hub, ["ip", "link", "del", "dev", host.veth])
        self._gone.add(host.label)
        self._chained.discard(host.label)

    def clear(self, host: Host | str) -> None:
        """Remove every fault from the host's link: no loss, no shaping, link up."""
        host = self._host(host)
        if host.label in self._chained:
            inbound, outbound = self._chains(host)
            self._nft(f"flush chain netdev {TABLE} {inbound}\nflush chain netdev {TABLE} {outbound}\n")
        for where, device in ((self.topology.hub, host.veth), (host, HOST_IFACE)):
            try:
                self.topology.run(where, ["tc", "qdisc", "del", "dev", device, "root"])
            except RuntimeError:
                pass  # no qdisc of ours there
        self.restore(host)
