"""What an intruder on the network tries against a secure run, as a program run on a host of the bench.

It uses this project's own client code (an intruder can read it too), so it lives with the tests,
not in harness/, which drives the system only from outside.

``python tests/hostile_client.py --router tcp/HUB:7447 --replay tcp://HUB:5560 --run RUN --certs DIR
--stolen actor.box1-actor-0 --victim box2-actor-0 --server-key DIR/curve/replay.key`` prints one
JSON object, what each attempt got from where the intruder stands:

- ``no_certificate``, ``stranger_authority``: a Zenoh client without a certificate, and one
  with a certificate from another authority (``c2farm certs`` elsewhere): ``"refused"`` when
  the router turned it away at open;
- with the stolen actor certificate (``--stolen``, its files copied off a box), it puts forged
  weights, an episode on the victim's key, a status under the learner's name, and listens to
  the victim's acknowledgements. A denied put is dropped silently at the router, so whether a
  put got through is judged by the receivers (the run's counters), not here; ``acks_heard``
  is what it received on the victim's acknowledgement key;
- ``batch_without_key``, ``batch_with_stranger_key``: a batch asked of the replay's ZeroMQ
  endpoint in plaintext and with a CURVE pair the replay never allowed (an actor has none):
  ``"nothing"`` when no batch came within the timeout.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path

FORGED = b"\x00forged by an intruder\xff"


def _refused(open_client) -> str:
    try:
        session = open_client()
    except ConnectionError:
        return "refused"
    session.close()
    return "opened"


def _stolen_certificate(router: str, certs: str, stolen: str, run: str, victim: str, listen_s: float) -> dict:
    from protocol import keys
    from protocol.fabric import FabricConfig, open_session

    session = open_session(FabricConfig(connect=[router], certs=certs, identity=stolen))
    heard: list[bytes] = []
    lock = threading.Lock()

    def on_ack(sample) -> None:
        with lock:
            heard.append(bytes(sample.payload.to_bytes()))

    try:
        subscriber = session.declare_subscriber(keys.acks(run, victim), on_ack)
        forged = {
            "weights": keys.weights(run),
            "victim_episode": keys.episodes(run, victim),
            "learner_status": keys.status(run, "learner", "learner"),
        }
        publishers = {name: session.declare_publisher(key) for name, key in forged.items()}
        time.sleep(0.5)  # a declared publisher sends only once it learnt of matching subscribers
        for _ in range(3):
            for publisher in publishers.values():
                publisher.put(FORGED)
            time.sleep(0.2)
        time.sleep(listen_s)
        subscriber.undeclare()
    finally:
        session.close()
    return {"opened": True, "forged_puts": sorted(forged), "acks_heard": len(heard)}


def _batch(endpoint: str, timeout_s: float, server_key: str = "") -> str:
    """"nothing" when the replay sent no batch within ``timeout_s``; "batch" if it did."""
    from protocol.sample_wire import ReplayClient, ReplayError, ReplayTimeout

    curve = {}
    if server_key:
        import zmq.auth

        keys_dir = tempfile.mkdtemp(prefix="intruder-")
        _, secret = zmq.auth.create_certificates(keys_dir, "intruder")
        Path(secret).chmod(0o600)  # our client refuses a secret key others may read
        curve = {"curve_certificate": secret, "curve_server_key": server_key}
    with ReplayClient(endpoint, batch_size=2, prefetch=1, request_timeout_s=timeout_s, **curve) as client:
        try:
            client.sample(timeout_s=timeout_s)
        except (ReplayTimeout, ReplayError):
            return "nothing"
    return "batch"


def attempts(args: argparse.Namespace) -> dict:
    from deploy.certs import CertsPlan, make_certs
    from protocol.fabric import FabricConfig, open_session

    stranger = Path(tempfile.mkdtemp(prefix="stranger-certs-"))
    make_certs(CertsPlan(stranger, actors=0, extra=[args.stolen]))
    insecure = FabricConfig(connect=[args.router], insecure=True)
    return {
        "no_certificate": _refused(lambda: open_session(insecure)),
        "stranger_authority": _refused(
            lambda: open_session(FabricConfig(connect=[args.router], certs=str(stranger), identity=args.stolen))),
        "stolen_certificate": _stolen_certificate(args.router, args.certs, args.stolen, args.run, args.victim,
                                                  args.listen_s),
        "batch_without_key": _batch(args.replay, args.timeout_s),
        "batch_with_stranger_key": _batch(args.replay, args.timeout_s, args.server_key),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="hostile_client.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--router", required=True, help="the router's endpoint, e.g. tcp/10.0.0.1:7447")
    parser.add_argument("--replay", required=True, help="the replay's ZeroMQ endpoint, e.g. tcp://10.0.0.1:5560")
    parser.add_argument("--run", required=True, help="the run id")
    parser.add_argument("--certs", required=True, help="the directory holding the stolen certificate")
    parser.add_argument("--stolen", required=True, help="the stolen identity, role.instance")
    parser.add_argument("--victim", required=True, help="another actor's instance name")
    parser.add_argument("--server-key", required=True, help="the replay's CURVE public key file (public anyway)")
    parser.add_argument("--timeout-s", type=float, default=5.0, help="how long to wait for a batch")
    parser.add_argument("--listen-s", type=float, default=3.0, help="how long to listen to the victim's acks")
    args = parser.parse_args(argv)
    json.dump(attempts(args), sys.stdout)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
