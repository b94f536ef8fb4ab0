"""CURVE on the learner <-> replay ZeroMQ link: real sockets on loopback, the sample service in-process.

Keys are made the way ``c2farm certs`` makes them (``zmq.auth.create_certificates``, secret
files 0600): the replay's pair, the learner's pair, and an allow-list directory holding the
learner's public key. Only a client holding an allowed key and the replay's public key gets
batches; everyone else gets nothing, and the replay counts each failed handshake by reason
without letting a retrying client flood its log.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import zmq.auth
from conftest import get_free_port, wait_for
from synthetic_episodes import synthetic_episode

from protocol.sample_wire import ReplayClient, ReplayError, ReplayTimeout
from replay_server.config import ReplayConfig
from replay_server.sample_service import SampleService
from replay_server.state import ReplayState

SIZE = 8


@dataclass
class Keys:
    replay_secret: str  #: the replay's NAME.key_secret (replay.curve_certificate)
    replay_public: str  #: the replay's NAME.key (learner.curve_server_key)
    learner_secret: str  #: the learner's NAME.key_secret (learner.curve_certificate)
    clients: str  #: the allow-list directory (replay.curve_clients): the learner's public key only
    stranger_secret: str  #: a well-formed key pair the replay has never heard of
    stranger_public: str


def make_keys(directory: Path) -> Keys:
    made = {}
    for name in ("replay", "learner", "stranger"):
        public, secret = zmq.auth.create_certificates(directory, name)
        os.chmod(secret, 0o600)
        made[name] = (public, secret)
    (directory / "clients").mkdir()
    shutil.copy(made["learner"][0], directory / "clients")
    return Keys(made["replay"][1], made["replay"][0], made["learner"][1], str(directory / "clients"),
                made["stranger"][1], made["stranger"][0])


@pytest.fixture
def keys(tmp_path) -> Keys:
    return make_keys(tmp_path)


@pytest.fixture
def make_service(tmp_path):
    """``make_service(**replay_settings)``: a started sample service over two stored episodes."""
    made = []

    def make(**settings) -> SampleService:
        config = ReplayConfig(**({"zmq_endpoint": f"tcp://127.0.0.1:{get_free_port()}", "min_size_to_sample": 1,
                                  "checkpoint_dir": str(tmp_path / "replay")} | settings))
        state = ReplayState.create(config, seed=1)
        for i in range(2):
            episode = synthetic_episode("a0", i, size=SIZE)
            state.store.insert(episode)
            state.limiter.inserts += episode.num_steps
        service = SampleService(state)
        service.start()
        made.append(service)
        return service

    yield make
    for service in made:
        service.close()


def curve_service(make_service, keys: Keys, **settings) -> SampleService:
    return make_service(curve_certificate=keys.replay_secret, curve_clients=keys.clients, **settings)


def learner_client(service: SampleService, keys: Keys, **kwargs) -> ReplayClient:
    """What learner.train does with learner.curve_certificate / learner.curve_server_key set."""
    return ReplayClient(service.endpoint, kwargs.pop("batch_size", 4), prefetch=kwargs.pop("prefetch", 1),
                        curve_certificate=keys.learner_secret, curve_server_key=keys.replay_public, **kwargs)


def test_a_learner_with_the_right_keys_samples_and_updates_priorities_over_curve(make_service, keys, caplog):
    service = curve_service(make_service, keys)
    stats = service.state.stats
    with learner_client(service, keys) as client:
        batch = client.sample(timeout_s=20)
        assert batch.arrays["indices"].shape == (4,)
        client.update_priorities(batch.arrays["indices"], batch.arrays["keys"], np.full(4, 2.0))
        wait_for(lambda: service.state.store.counters["priority_updates"] == 4, 10, "the priority update")
        assert client.handshakes == 1 and client.handshake_failures == 0
    # a refusal names the client by its key file and public key
    with caplog.at_level(logging.WARNING, logger="replay_server"):
        with learner_client(service, keys, batch_size=service.config.max_batch_size + 1) as too_big:
            with pytest.raises(ReplayError, match="max_batch_size"):
                too_big.sample(timeout_s=20)
    assert "batch_too_large from learner (key " in caplog.text
    assert stats["batches_served"] >= 1 and stats["zmq_rejected_auth"] == 0 and stats["zmq_rejected_handshake"] == 0


def test_clients_without_the_keys_get_nothing_are_counted_and_the_learner_keeps_sampling(make_service, keys, caplog):
    service = curve_service(make_service, keys)
    stats = service.state.stats
    strangers = {  # what each gets told when its sample times out
        "plaintext": dict(),
        "unknown key": dict(curve_certificate=keys.stranger_secret, curve_server_key=keys.replay_public),
        "wrong server key": dict(curve_certificate=keys.learner_secret, curve_server_key=keys.stranger_public),
    }
    with caplog.at_level(logging.WARNING, logger="replay_server"), learner_client(service, keys) as learner:
        for name, kwargs in strangers.items():
            with ReplayClient(service.endpoint, 4, prefetch=2, **kwargs) as stranger:
                started = time.monotonic()
                with pytest.raises(ReplayTimeout, match="handshake") as err:
                    stranger.sample(timeout_s=1.5)
                assert time.monotonic() - started < 5, name  # bounded: the caller's timeout, not a hang
                assert "\n" not in str(err.value)
                assert stranger.handshakes == 0, name
            assert learner.sample(timeout_s=20).arrays["indices"].shape == (4,)  # meanwhile, served as ever
        # the unknown key is refused by the authenticator, the other two fail the handshake itself
        wait_for(lambda: stats["zmq_rejected_auth"] >= 1 and stats["zmq_rejected_handshake"] >= 2, 10,
                 "the replay to count the failed handshakes")
    assert stats["batches_served"] >= len(strangers)
    assert stats["zmq_rejected"] == stats["zmq_rejected_auth"] + stats["zmq_rejected_handshake"]


def test_a_client_retrying_with_a_wrong_server_key_is_counted_without_flooding_the_log(make_service, keys, caplog):
    service = curve_service(make_service, keys, reject_log_interval_s=60.0)
    stats = service.state.stats
    with caplog.at_level(logging.WARNING, logger="replay_server"):
        with ReplayClient(service.endpoint, 4, curve_certificate=keys.learner_secret,
                          curve_server_key=keys.stranger_public) as wrong:
            with pytest.raises(ReplayTimeout, match=r"handshake with the replay failed \d+ times?"):
                wrong.sample(timeout_s=2.0)  # libzmq reconnects every ~100-200 ms meanwhile
        wait_for(lambda: stats["zmq_rejected_handshake"] >= 3, 10, "several failed handshakes")
    lines = [r for r in caplog.records if "zmq rejected handshake" in r.getMessage()]
    assert len(lines) == 1, [r.getMessage() for r in lines]
    assert "another server key" in lines[0].getMessage()


def test_the_per_client_limit_follows_the_key_not_the_connection(make_service, keys):
    """Two connections with one key share its pending limit (two identities would not get twice as much)."""
    service = curve_service(make_service, keys, min_size_to_sample=10**6, max_pending_per_client=2)
    stats = service.state.stats
    with learner_client(service, keys, prefetch=2) as a, learner_client(service, keys, prefetch=2) as b:
        for client in (a, b):
            with pytest.raises(ReplayTimeout):
                client.sample(timeout_s=0.5)
        wait_for(lambda: stats["zmq_rejected_pending_per_client"] >= 1, 10, "the per-key limit")
        assert service.pending <= 2


def test_a_plaintext_replay_counts_a_curve_learner_and_the_learner_says_why(make_service, keys):
    service = make_service()  # CURVE off: plaintext, as without keys
    with learner_client(service, keys) as client:
        with pytest.raises(ReplayTimeout, match="handshake") as err:
            client.sample(timeout_s=1.5)
    assert "\n" not in str(err.value)
    wait_for(lambda: service.state.stats["zmq_rejected_handshake"] >= 1, 10, "the mismatch to be counted")
    with ReplayClient(service.endpoint, 4, prefetch=1) as plaintext:
        assert plaintext.sample(timeout_s=20).arrays["indices"].shape == (4,)


def test_a_client_is_refused_a_half_set_pair():
    with pytest.raises(ValueError, match="both"):
        ReplayClient("tcp://127.0.0.1:1", 4, curve_certificate="x.key_secret")
