"""Weights travel learner -> actors over Zenoh: versioned, newest-wins, late joiners catch up."""

import socket
import time

import torch

from protocol.fabric import FabricConfig, open_session
from protocol.weights_follower import WeightsFollower, tensors_from_update
from protocol.weights_publisher import WeightsPublisher


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(predicate, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        result = predicate()
        if result:
            return result
        time.sleep(0.02)
    raise AssertionError("condition not met in time")


def test_actor_gets_newest_version_and_late_joiner_queries_it():
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    router = open_session(FabricConfig(listen=[endpoint]), "router")
    learner = open_session(FabricConfig(connect=[endpoint]))
    actor = open_session(FabricConfig(connect=[endpoint]))
    try:
        publisher = WeightsPublisher(learner, "run", config_digest="abc")
        follower = WeightsFollower(actor, "run", expected_digest="abc")
        time.sleep(0.3)  # let the subscription reach the router before the first put
        weights = {"net.w": torch.arange(6, dtype=torch.float32).reshape(2, 3)}
        for version in (1, 2, 3):
            publisher.publish({k: v * version for k, v in weights.items()}, version, learner_step=10 * version)
        time.sleep(0.3)  # let the burst land: asked mid-burst, the follower would rightly offer what it had
        update = _wait(follower.newer)
        assert update.version == 3  # of a burst, only the newest is offered
        assert torch.equal(tensors_from_update(update)["net.w"], weights["net.w"] * 3)
        follower.version = update.version
        assert follower.newer() is None  # nothing newer since

        late = WeightsFollower(actor, "run", expected_digest="abc")
        late.fetch_latest(timeout_s=5.0)
        assert late.newer().version == 3

        wrong = WeightsFollower(actor, "run", expected_digest="other-network")
        wrong.fetch_latest(timeout_s=5.0)
        assert wrong.newer() is None and wrong.rejected == 1
        for f in (follower, late, wrong):
            f.close()
        publisher.close()
    finally:
        for s in (actor, learner, router):
            s.close()
