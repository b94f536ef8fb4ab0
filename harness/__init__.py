"""A multi-host test bench on one Linux machine: network namespaces joined by a bridge.

Each "machine" is a network namespace with its own address, ports and ``/dev/shm``; a hub
namespace holds the bridge they all plug into, so the root namespace is never touched. Faults
(loss, bandwidth, a pulled cable, a host that vanishes) are made on the hub's side of one
host's link, and a small TCP proxy adds a fixed delay (the kernel here has no netem).

Tests and benchmarks drive the system through its CLI inside these namespaces; nothing here
imports the project's roles, so the bench is what a second machine would see, nothing more.
"""

from harness.faults import Faults
from harness.inside import inside
from harness.netns import Host, Topology, probe
from harness.processes import Started

__all__ = ["Faults", "Host", "Started", "Topology", "inside", "probe"]
