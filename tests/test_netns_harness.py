"""The multi-host bench itself (harness/): namespaces on a bridge, faults on a link, a delay proxy, cleanup.

Sockets are opened from this process inside the bench's namespaces (harness.inside), so most
checks start no process at all. Figures (loss measured, time to heal a cut, throughput under
a shaped link, round trips through the proxy) are printed: run with -s to read them.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest
from conftest import REPO, survivors, wait_for

from harness import Faults, Topology, probe
from harness.netns import namespaces

WHY_NOT = probe()
pytestmark = [pytest.mark.skipif(WHY_NOT is not None, reason=f"no network namespaces here: {WHY_NOT}"),
              pytest.mark.timeout(180)]


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Iterator[tuple[Topology, Faults]]:
    with Topology(["a", "b"], tmp_path_factory.mktemp("netns-logs")) as topology:
        yield topology, Faults(topology)


def listener(topology: Topology, host: str, port: int = 0) -> socket.socket:
    """A TCP listener bound to ``host``'s address, inside its namespace."""
    with topology.inside(host):
        return socket.create_server((topology.host(host).ip, port))


def connect(topology: Topology, host: str, address: tuple[str, int], timeout: float = 5.0) -> socket.socket:
    with topology.inside(host):
        return socket.create_connection(address, timeout=timeout)


def echo_server(server: socket.socket) -> None:
    """Echo every connection accepted on ``server`` (threads; ends when the server socket closes)."""

    def echo(conn: socket.socket) -> None:
        with conn:
            while data := conn.recv(65536):
                conn.sendall(data)

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            threading.Thread(target=echo, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()


def udp_loss(topology: Topology, sender: str, receiver: str, count: int = 2000) -> float:
    """Fraction of ``count`` datagrams from ``sender`` that never reach ``receiver``.

    Sent in batches drained before the next, so a full receive buffer never counts as loss.
    """
    with topology.inside(receiver):
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.bind((topology.host(receiver).ip, 0))
    with topology.inside(sender):
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    received = 0
    with rx, tx:
        rx.settimeout(0.05)
        for start in range(0, count, 100):
            for i in range(start, min(count, start + 100)):
                tx.sendto(i.to_bytes(4, "big"), rx.getsockname())
            try:
                while True:
                    rx.recv(16)
                    received += 1
            except socket.timeout:
                pass
    return 1 - received / count


def test_tcp_crosses_the_bridge_and_a_process_runs_inside_its_host(bench, tmp_path: Path):
    topology, _ = bench
    server = listener(topology, "hub")
    with server:
        for host in ("a", "b"):
            with connect(topology, host, server.getsockname()) as client:
                conn, (peer, _) = server.accept()
                with conn:
                    assert peer == topology.host(host).ip  # no NAT: the hub sees the host's own address
                    client.sendall(b"ping")
                    assert conn.recv(4) == b"ping"
        # hosts reach each other across the bridge too
        other = listener(topology, "b")
        with other, connect(topology, "a", other.getsockname()):
            other.accept()[0].close()

        # a started process: inside its host, with this process's environment plus what we pass
        code = ("import os, socket; s = socket.create_connection((os.environ['HUB'], int(os.environ['PORT'])), 5); "
                "s.sendall(os.environ['WHO'].encode()); open('/dev/shm/harness-mark', 'w').write('b'); "
                "print('sent from', s.getsockname()[0])")
        proc = topology.spawn("b", [sys.executable, "-c", code], "client", cwd=REPO,
                              env={"HUB": topology.hub.ip, "PORT": str(server.getsockname()[1]), "WHO": "b-proc"})
        conn, (peer, _) = server.accept()
        with conn:
            assert conn.recv(16) == b"b-proc" and peer == topology.host("b").ip
        assert proc.popen.wait(timeout=30) == 0
    assert f"sent from {topology.host('b').ip}" in proc.output()
    assert proc.log.parent == topology.log_dir and proc.log.name == "b-client.log"
    # its /dev/shm was its host's own: no other host, nor the machine, shares memory with it
    assert (topology.host("b").shm / "harness-mark").exists()
    assert not Path("/dev/shm/harness-mark").exists() and not (topology.host("a").shm / "harness-mark").exists()


def test_loss_drops_about_the_share_asked_for_each_way_and_clear_removes_it(bench):
    topology, faults = bench
    faults.loss("a", 5)
    try:
        up, down = udp_loss(topology, "a", "hub"), udp_loss(topology, "hub", "a")
        other = udp_loss(topology, "b", "hub")
    finally:
        faults.clear("a")
    print(f"\nloss set to 5 %: measured {up:.1%} a->hub, {down:.1%} hub->a; b (no fault) {other:.1%}")
    assert 0.01 <= up <= 0.15 and 0.01 <= down <= 0.15
    assert other < 0.01  # one host's fault is on its link only
    assert udp_loss(topology, "a", "hub") < 0.01


def test_a_cut_is_a_pulled_cable_silence_without_reset_and_restore_heals_it(bench):
    topology, faults = bench
    server = listener(topology, "hub")
    with server, connect(topology, "a", server.getsockname()) as client:
        conn, _ = server.accept()
        conn.settimeout(1.0)
        faults.cut("a")
        cut_at = time.monotonic()
        try:
            client.sendall(b"sent during the cut")
            with pytest.raises(socket.timeout):
                conn.recv(64)  # nothing arrives...
            with pytest.raises(socket.timeout):  # ...and a new connection hangs: no RST, no refusal
                connect(topology, "a", server.getsockname(), timeout=1.0)
            with connect(topology, "b", server.getsockname()):  # the other host is not affected
                server.accept()[0].close()
        finally:
            faults.restore("a")
        cut_over = time.monotonic()
        cut_s = cut_over - cut_at
        conn.settimeout(30)
        data = b""
        while len(data) < len(b"sent during the cut"):
            data += conn.recv(64)
        healed = time.monotonic() - cut_over
        assert data == b"sent during the cut"  # TCP retransmitted it once the cable was back
        conn.sendall(b"and back")  # the same connection, both ways: it was never reset
        assert client.recv(8) == b"and back"
        conn.close()
    print(f"\nafter restore, the bytes sent during a {cut_s:.1f} s cut arrived in {healed:.2f} s (TCP retransmission)")


def test_bandwidth_shapes_both_directions(bench):
    topology, faults = bench
    payload = os.urandom(256 * 1024)

    def transfer(sender: str, receiver: str) -> float:
        server = listener(topology, receiver)
        with server, connect(topology, sender, server.getsockname()) as client:
            conn, _ = server.accept()
            with conn:
                conn.settimeout(30)
                started = time.monotonic()
                threading.Thread(target=client.sendall, args=(payload,), daemon=True).start()
                got = 0
                while got < len(payload):
                    got += len(conn.recv(65536))
                return time.monotonic() - started

    faults.bandwidth("a", "2mbit")  # 250 kB/s: 256 kB takes about a second, less the 32 kB burst
    try:
        up, down = transfer("a", "hub"), transfer("hub", "a")
    finally:
        faults.clear("a")
    free = transfer("a", "hub")
    print(f"\n2 mbit shaping: 256 kB up in {up:.2f} s ({len(payload) * 8 / up / 1e6:.2f} Mbit/s), down in "
          f"{down:.2f} s; unshaped {free * 1e3:.0f} ms")
    assert up >= 0.5 and down >= 0.5  # a lower bound: a busy machine only makes it slower


def test_the_delay_proxy_adds_its_delay_each_way_and_keeps_bytes_in_order(bench):
    topology, _ = bench
    server = listener(topology, "hub")
    echo_server(server)
    a = topology.host("a")
    proxy = topology.spawn("a", [sys.executable, "-m", "harness.delay_proxy", "--listen", f"{a.ip}:7000",
                                 "--target", f"{topology.hub.ip}:{server.getsockname()[1]}", "--delay-ms", "100"],
                           "delay-proxy", cwd=REPO)
    try:
        topology.wait_listening("a", a.ip, 7000)
        with server, connect(topology, "b", (a.ip, 7000), timeout=30) as client:  # b -> proxy on a -> hub
            rtts = []
            for i in range(5):
                started = time.monotonic()
                client.sendall(b"%d" % i)
                assert client.recv(8) == b"%d" % i
                rtts.append(time.monotonic() - started)
            data = os.urandom(1 << 20)
            threading.Thread(target=client.sendall, args=(data,), daemon=True).start()
            echoed = bytearray()
            while len(echoed) < len(data):
                echoed += client.recv(1 << 16)
            assert bytes(echoed) == data  # a megabyte each way through the delays, nothing reordered
        print(f"\nround trips through a 100 ms delay proxy: {', '.join(f'{r * 1e3:.0f}' for r in rtts)} ms")
        assert min(rtts) >= 0.2
        assert "listening on" in proxy.output()
    finally:
        assert topology.stop(proxy, timeout=10) is not None


def test_vanish_kills_the_host_and_removes_its_link_and_nothing_outlives_the_bench(tmp_path: Path):
    root_links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout
    seen: list[psutil.Process] = []
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C in the middle of a test cleans up like a pass
        with Topology(2, tmp_path) as topology:
            faults = Faults(topology)
            names, shm = topology.namespaces(), [h.shm for h in (topology.hub, *topology.hosts)]
            # a process that escapes its process group (setsid): only the namespace sweep finds it
            for host in ("h1", "h2"):
                topology.spawn(host, ["sh", "-c", "setsid sleep 300 & exec sleep 300"], "sleepers")
            wait_for(lambda: len(topology.pids("h1")) >= 2 and len(topology.pids("h2")) >= 2, 30,
                     "the sleepers to start")
            seen = [psutil.Process(p) for host in ("h1", "h2") for p in topology.pids(host)]
            assert subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout == root_links

            h2 = topology.host("h2")
            faults.vanish("h2")
            assert topology.pids("h2") == []
            veths = subprocess.run(["ip", "-n", topology.hub.netns, "-o", "link"], capture_output=True,
                                   text=True).stdout
            assert h2.veth not in veths and topology.host("h1").veth in veths
            with pytest.raises(OSError):
                connect(topology, "hub", (h2.ip, 22), timeout=1.0)
            with pytest.raises(ValueError, match="vanished"):
                faults.cut("h2")
            raise KeyboardInterrupt
    left = set(names) & set(namespaces())
    assert not left, f"namespaces left behind: {left}"
    assert not survivors(seen), f"processes left behind: {survivors(seen)}"
    assert not any(path.exists() for path in shm)
    assert subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout == root_links


def test_a_bench_its_creator_forgot_goes_at_exit_and_one_whose_creator_was_killed_goes_at_the_next_start(
        tmp_path: Path):
    make = ("import os, sys; from harness import Topology; t = Topology(1, sys.argv[1]).__enter__(); "
            "print(' '.join(t.namespaces()), flush=True); t.spawn('h1', ['sleep', '300'], 'sleeper'); ")

    def leave(how: str) -> list[str]:
        out = subprocess.run([sys.executable, "-c", make + how, str(tmp_path)], cwd=REPO, capture_output=True,
                             text=True, timeout=120)
        return out.stdout.split()

    forgotten = leave("sys.exit(0)")  # no close(): the atexit backstop
    assert forgotten and not set(forgotten) & set(namespaces())
    killed = leave("os.kill(os.getpid(), 9)")  # no chance to clean up at all
    assert killed and set(killed) <= set(namespaces())
    with Topology(1, tmp_path):
        assert not set(killed) & set(namespaces())  # swept: its creator is dead
