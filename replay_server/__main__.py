"""``python -m replay_server``: run the replay role standalone (tests, multi-machine setups)."""
from __future__ import annotations

import argparse
import logging
import sys

from protocol.fabric import FabricConfig
from protocol.role import RoleContext, stop_on_signals
from replay_server.config import ReplayConfig, apply_overrides
from replay_server.service import run


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m replay_server", description=__doc__)
    p.add_argument("--run-id", required=True)
    p.add_argument("--instance", default="replay")
    p.add_argument("--run-dir", required=True)
    p.add_argument("--connect", action="append", default=None, help="zenoh router endpoint (repeatable)")
    p.add_argument("--zmq-endpoint", default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-shm", action="store_true", help="disable zenoh shared memory")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="any ReplayConfig field")
    p.add_argument("--log-level", default="INFO")
    a = p.parse_args(argv)
    logging.basicConfig(level=a.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    config = apply_overrides(ReplayConfig(), a.set)
    if a.zmq_endpoint:
        config.zmq_endpoint = a.zmq_endpoint
    fabric = FabricConfig(connect=a.connect or FabricConfig().connect, shared_memory=not a.no_shm)
    ctx = RoleContext(run_id=a.run_id, instance=a.instance, run_dir=a.run_dir, seed=a.seed, fabric=fabric)
    stop_on_signals(ctx.stop)
    return run(config, ctx)


if __name__ == "__main__":
    sys.exit(main())
