"""Run a block of Python in another network namespace, on the calling thread only.

A test process lives in the root namespace, where none of the bench's addresses exist. To
open a socket on a host of the bench (a client, a listener, an HTTP request to a dashboard
bound to that host's 127.0.0.1) without starting a process, the calling thread switches its
network namespace with setns(2) and back. A socket keeps the namespace it was created in, so
it can be used after the block; other threads are not affected. Python 3.11 has no
``os.setns``, hence ctypes.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

CLONE_NEWNET = 0x40000000
NETNS_DIR = Path("/run/netns")  #: where ``ip netns add`` pins a namespace

_libc = ctypes.CDLL(None, use_errno=True)


def _setns(fd: int) -> None:
    if _libc.setns(fd, CLONE_NEWNET) != 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"setns: {os.strerror(errno)}")


@contextmanager
def inside(netns: str) -> Iterator[None]:
    """Put the calling thread in namespace ``netns`` (an ``ip netns`` name) for the block."""
    own = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    try:
        target = os.open(NETNS_DIR / netns, os.O_RDONLY)
        try:
            _setns(target)
        finally:
            os.close(target)
        try:
            yield
        finally:
            _setns(own)
    finally:
        os.close(own)
