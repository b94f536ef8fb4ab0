"""Weights versions mean one thing: never reused (across learner restarts too), and an actor follows
the versions the learner announces, so no crafted message on the weights key can freeze or crash it."""

import numpy as np
import pytest
import torch
from conftest import wait_for

from actors.actor_loop import ActingPolicy
from actors.config import ActorConfig
from learner.config import LearnerConfig
from learner.train import Learner
from protocol import Status, WeightsUpdate, encode, keys
from protocol.codec import encode_frame
from protocol.fabric import open_session
from protocol.heartbeat import Heartbeat
from protocol.messages import Kind
from protocol.role import RoleContext
from protocol.weights_follower import WeightsFollower
from protocol.weights_publisher import WeightsPublisher
from qattention import QAttentionConfig
from qattention.digest import network_digest

RUN = "run-1"
TINY = QAttentionConfig(voxel_size=8, kernels=4, head_width=16, padding="zeros", image_crop=16, rotation_resolution=30)
W = {"net.w": torch.arange(6, dtype=torch.float32).reshape(2, 3)}

pytestmark = pytest.mark.parametrize("shm", [False])  # the fabric's shm path is covered elsewhere


@pytest.fixture
def sessions(router):
    opened = [open_session(router) for _ in range(3)]
    try:
        yield opened  # learner, actor, forger
    finally:
        for s in opened:
            s.close()


class FakeLearner:
    """The real publisher and heartbeat, driven by hand: announce, then send (as learner/train.py does)."""

    def __init__(self, session, digest="abc"):
        self.version = 0
        self.publisher = WeightsPublisher(session, RUN, digest)
        self.beat = Heartbeat(session, RUN, "learner", "learner", counters=lambda: {"weights_version": self.version},
                              period_s=0.2)

    def publish(self, version, weights=W):
        self.version = version
        self.beat.publish()
        return self.publisher.publish({k: v * version for k, v in weights.items()}, version, learner_step=version)

    def close(self):
        self.beat.close()
        self.publisher.close()


def forged(version, tensors=None, digest="abc") -> bytes:
    tensors = {"net.w": np.full((2, 3), 7.0, np.float32)} if tensors is None else tensors
    return encode(WeightsUpdate(version, 0, tensors, digest))


def nan_frame(version, tensors, digest) -> bytes:
    """A weights message with NaN inside, framed by hand: ``encode`` refuses to build one."""
    nan = {k: np.full_like(a, np.nan) for k, a in tensors.items()}
    fields = {"version": version, "learner_step": 0, "config_digest": digest, "published_at": 0.0, "env_steps": 0}
    return encode_frame(Kind.WEIGHTS, fields, nan)


def take(follower, version=None):
    """Wait for the follower to offer an update (of ``version``), and make it current."""
    update = wait_for(lambda: (u := follower.newer()) and (version is None or u.version == version) and u, 30,
                      f"weights version {version}")
    assert follower.adopt(update, lambda tensors: None)
    return update


def test_a_restarted_learner_never_reuses_a_version(tmp_path, sessions):
    learner_session, actor_session, _ = sessions
    ctx, config = RoleContext(RUN, "learner", tmp_path), LearnerConfig(device="cpu")
    first = Learner(config, TINY, ctx)
    publisher = WeightsPublisher(learner_session, RUN, network_digest(TINY))
    assert first.publish(publisher) and first.checkpoint()  # the checkpoint says version 1
    assert first.publish(publisher) and first.publish(publisher)  # 2 and 3 go out after it
    publisher.close()

    second = Learner(config, TINY, ctx)  # a restart: resumes the checkpoint, not its version
    assert second.version == 3
    publisher = WeightsPublisher(learner_session, RUN, network_digest(TINY))
    follower = WeightsFollower(actor_session, RUN, network_digest(TINY))
    assert second.publish(publisher)
    follower.fetch_latest(timeout_s=5.0)
    assert follower.newer().version == 4
    follower.close()
    publisher.close()


def test_a_forged_huge_version_is_ignored_and_real_versions_still_followed(sessions):
    learner_session, actor_session, forger = sessions
    learner = FakeLearner(learner_session)
    follower = WeightsFollower(actor_session, RUN, "abc")
    try:
        wait_for(lambda: follower.announced == 0, 30, "the learner's heartbeat at the actor")
        learner.publish(1)
        take(follower, 1)

        forger.put(keys.weights(RUN), forged(10**12))
        wait_for(lambda: follower.newer() is None and follower.rejected_by["not_announced"], 30, "the forgery seen")
        assert follower.version == 1

        learner.publish(2)
        assert torch.equal(torch.from_numpy(take(follower, 2).tensors["net.w"]), W["net.w"] * 2)
        assert follower.counters()["weights_rejected_not_announced"] == 1
    finally:
        follower.close()
        learner.close()


def test_an_actor_that_took_a_forgery_before_any_announcement_resyncs_down(sessions):
    learner_session, actor_session, forger = sessions
    publisher = WeightsPublisher(learner_session, RUN, "abc")
    publisher.publish(W, 1, learner_step=1)  # the learner's latest, before the actor hears from it
    follower = WeightsFollower(actor_session, RUN, "abc", resync_every_s=0.1)
    try:
        def forgery_pending():  # the learner's v1, published just before, may still be in flight: skip it
            forger.put(keys.weights(RUN), forged(10**12))
            update = follower.newer()
            return update if update is not None and update.version == 10**12 else None

        update = wait_for(forgery_pending, 30, "the forgery")
        # Nothing announced yet, so nothing to check it against: the forgery is taken.
        assert follower.adopt(update, lambda tensors: None) and follower.version == 10**12

        beat = Heartbeat(learner_session, RUN, "learner", "learner", counters=lambda: {"weights_version": 1},
                         period_s=0.2)
        take(follower, 1)  # announced 1 < in use: the follower asks the queryable and goes back to 1
        beat.close()
    finally:
        follower.close()
        publisher.close()


def test_crafted_weights_messages_are_counted_by_reason_and_never_raise(sessions):
    learner_session, actor_session, forger = sessions
    learner = FakeLearner(learner_session, digest=network_digest(TINY))
    follower = WeightsFollower(actor_session, RUN, network_digest(TINY))
    policy = ActingPolicy(TINY, follower)
    try:
        wait_for(lambda: follower.announced == 0, 30, "the learner's heartbeat at the actor")
        learner.version = 5
        learner.beat.publish()
        wait_for(lambda: follower.announced == 5, 30, "announcement of version 5")
        good = {k: t.numpy() for k, t in policy.agent.weights().items()}
        crafted = {
            "decode_error": [b"\x00garbage", b"C2FA" + b"\xff" * 40,
                             encode(Status("learner", "learner", RUN, 1, "h", 0.0))],
            "bad_digest": [forged(3, good, digest="another-network")],
            "non_finite": [nan_frame(3, good, network_digest(TINY))],
        }
        for reason, payloads in crafted.items():
            for n, payload in enumerate(payloads, 1):  # one at a time: the inbox keeps only the last few
                forger.put(keys.weights(RUN), payload)
                wait_for(lambda: follower.newer() is None and follower.rejected_by[reason] == n, 30, f"{reason} {n}")
        assert follower.version == 0

        # Announced and well-formed, but not these networks: refused at load, old weights kept.
        before = policy.agent.weights()
        forger.put(keys.weights(RUN), forged(4, {"net.0.not_a_parameter": np.zeros(3, np.float32)},
                                             digest=network_digest(TINY)))
        wait_for(lambda: not policy.refresh() and follower.rejected_by["bad_tensors"], 30, "the misfit refused")
        assert follower.version == 0 and all(torch.equal(before[k], t) for k, t in policy.agent.weights().items())

        # The real learner's weights are still taken.
        real = {k: t * 0.5 for k, t in before.items()}
        learner.publish(5, real)
        wait_for(policy.refresh, 30, "the real version 5")
        assert follower.version == 5
        assert all(torch.equal(t, real[k] * 5) for k, t in policy.agent.weights().items())
        assert follower.rejected == sum(len(p) for p in crafted.values()) + 1
    finally:
        follower.close()
        learner.close()


def test_the_publisher_refuses_non_finite_weights(sessions):
    learner_session, actor_session, _ = sessions
    publisher = WeightsPublisher(learner_session, RUN, "abc")
    follower = WeightsFollower(actor_session, RUN, "abc")
    try:
        assert publisher.publish(W, 1, learner_step=1) > 0
        assert publisher.publish({"net.w": torch.tensor([1.0, float("nan")])}, 2, learner_step=2) == 0
        assert publisher.refused == 1 and publisher.version == 1
        # the queryable still answers with the last good version (asked again until the follower's session has
        # learnt of the queryable: a query sent before that finds no one to answer it)
        update = wait_for(lambda: follower.fetch_latest(timeout_s=1.0) or follower.newer(), 15, "the queryable's reply")
        assert update.version == 1
        with pytest.raises(ValueError):
            publisher.publish(W, 1, learner_step=3)  # a version is never sent twice
    finally:
        follower.close()
        publisher.close()


def test_an_actor_anneals_its_exploration_with_the_learner_step_of_the_weights_it_runs(sessions):
    learner_session, actor_session, _ = sessions
    learner = FakeLearner(learner_session, digest=network_digest(TINY))
    follower = WeightsFollower(actor_session, RUN, network_digest(TINY))
    schedule = ActorConfig(epsilon=0.2, epsilon_final=0.0, epsilon_decay_updates=10).epsilon_at
    policy = ActingPolicy(TINY.replace(epsilon=0.2), follower, epsilon=schedule)
    weights = policy.agent.weights()
    try:
        for version, expected in ((5, 0.1), (20, 0.0)):  # FakeLearner publishes learner_step = version
            learner.publish(version, weights)
            wait_for(lambda: policy.refresh() or follower.version == version, 30, f"version {version}")
            assert policy.agent.config.epsilon == pytest.approx(expected)
    finally:
        follower.close()
        learner.close()
