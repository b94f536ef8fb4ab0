"""A TCP proxy that adds a fixed one-way delay in each direction: latency without netem.

This kernel has no ``sch_netem``, so a slow link is made in user space: every chunk read from
one side is written to the other ``delay`` later, in the order read (one reader and one writer
per direction, a FIFO between them), so bytes are never reordered and a round trip through
the proxy takes at least twice the delay. End-of-stream is delayed like data. Run it inside a
host's namespace and point a client at it instead of at the real server:

    python -m harness.delay_proxy --listen 10.77.0.11:7447 --target 10.77.0.1:7447 --delay-ms 100

It prints ``listening on HOST:PORT`` (the real port when asked for port 0) once it accepts.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
from collections.abc import Sequence

CHUNK = 64 * 1024
IN_FLIGHT = 256  #: chunks queued per direction before the reader waits (backpressure)


def parse_address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, delay_s: float) -> None:
    """Copy ``reader`` to ``writer``, each chunk (and the final EOF) ``delay_s`` after it was read."""
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue(IN_FLIGHT)

    async def read() -> None:
        try:
            while data := await reader.read(CHUNK):
                await queue.put((loop.time() + delay_s, data))
        except ConnectionError:
            pass  # a reset ends the stream like an EOF
        await queue.put((loop.time() + delay_s, b""))  # the end travels with the same delay

    async def write() -> None:
        while True:
            due, data = await queue.get()
            if (wait := due - loop.time()) > 0:
                await asyncio.sleep(wait)
            if not data:
                if writer.can_write_eof():
                    writer.write_eof()
                return
            writer.write(data)
            await writer.drain()

    reading = asyncio.ensure_future(read())
    try:
        await write()
    finally:
        reading.cancel()
        with contextlib.suppress(asyncio.CancelledError, ConnectionError):
            await reading


async def _connection(client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter, target: tuple[str, int],
                      delay_s: float) -> None:
    try:
        server_r, server_w = await asyncio.open_connection(*target)
    except OSError:
        client_w.close()
        return
    pumps = [asyncio.ensure_future(_pump(client_r, server_w, delay_s)),
             asyncio.ensure_future(_pump(server_r, client_w, delay_s))]
    try:
        await asyncio.gather(*pumps)
    except (ConnectionError, OSError):
        pass
    finally:
        for task in pumps:
            task.cancel()
        for w in (client_w, server_w):
            w.close()
            with contextlib.suppress(ConnectionError, OSError):
                await w.wait_closed()


async def serve(listen: tuple[str, int], target: tuple[str, int], delay_s: float) -> asyncio.Server:
    """Start proxying connections on ``listen`` to ``target``; the caller serves or closes the server."""
    return await asyncio.start_server(lambda r, w: _connection(r, w, target, delay_s), *listen)


async def _main(listen: tuple[str, int], target: tuple[str, int], delay_s: float) -> None:
    server = await serve(listen, target, delay_s)
    host, port = server.sockets[0].getsockname()[:2]
    print(f"listening on {host}:{port} -> {target[0]}:{target[1]} (+{delay_s * 1e3:.0f} ms each way)", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGTERM, signal.SIGINT):  # a stop request ends it cleanly, exit code 0
        loop.add_signal_handler(signum, stop.set)
    async with server:
        await stop.wait()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m harness.delay_proxy", description=__doc__.split("\n\n")[0])
    parser.add_argument("--listen", type=parse_address, required=True, help="HOST:PORT to accept on")
    parser.add_argument("--target", type=parse_address, required=True, help="HOST:PORT to forward to")
    parser.add_argument("--delay-ms", type=float, default=100.0, help="one-way delay added each way (ms, >= 0)")
    args = parser.parse_args(argv)
    if args.delay_ms < 0:
        parser.error("--delay-ms must be >= 0")
    asyncio.run(_main(args.listen, args.target, args.delay_ms / 1e3))
    return 0


if __name__ == "__main__":
    sys.exit(main())
