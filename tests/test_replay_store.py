"""Replay storage, PER, rate limiter, WAL and checkpoints (in-process, no network)."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from synthetic_episodes import actor_tag, synthetic_episode

from protocol import transition
from replay_server.checkpoint_files import list_checkpoints, load_checkpoint, load_latest, write_checkpoint
from replay_server.config import ReplayConfig, apply_overrides
from replay_server.ratelimiter import RateLimiter
from replay_server.storage import EpisodeStore
from replay_server.sumtree import SumTree
from replay_server.wal import WriteAheadLog, list_segments, read_segment, segment_path


def make_store(**kw) -> EpisodeStore:
    kw.setdefault("capacity_transitions", 200)
    kw.setdefault("min_size_to_sample", 1)
    return EpisodeStore(ReplayConfig(**kw))


def fill(store, n, actor="a", size=8, start=0, **kw):
    eps = [synthetic_episode(actor, start + i, size=size, **kw) for i in range(n)]
    for ep in eps:
        store.insert(ep)
    return eps


def check_batch_exact(batch: dict, episodes_by_key: dict, points_f16: bool = True) -> None:
    """Every sampled transition equals the source episode's data, bit for bit."""
    for i, (tag, eid, t) in enumerate(batch["extra_tag"]):
        ep = episodes_by_key[(int(tag), int(eid))]
        for name, arr in ep.observations.items():
            expect_t, expect_tp1 = arr[t], arr[t + 1]
            if points_f16 and name.endswith("_points"):
                expect_t, expect_tp1 = expect_t.astype(np.float16), expect_tp1.astype(np.float16)
            assert batch[name][i].tobytes() == np.ascontiguousarray(expect_t).tobytes(), name
            assert batch[name + "_tp1"][i].tobytes() == np.ascontiguousarray(expect_tp1).tobytes(), name
        assert batch["action"][i].tobytes() == ep.actions[t].tobytes()
        assert batch["reward"][i] == ep.rewards[t]
        assert batch["terminal"][i] == ep.terminals[t]
        assert batch["timeout"][i] == (ep.timeout and t == ep.num_steps - 1)
        assert batch["policy_version"][i] == ep.policy_versions[t]
        assert batch["is_demo"][i] == ep.is_demo


# ---------------------------------------------------------------- sum tree


def test_sumtree_find_matches_cumsum():
    rng = np.random.default_rng(1)
    tree = SumTree(37)
    p = rng.uniform(0, 2, 37)
    p[[3, 10, 11]] = 0.0
    tree.set(np.arange(37), p)
    assert tree.total == pytest.approx(p.sum())
    q = rng.uniform(0, p.sum(), 5000)
    expect = np.searchsorted(np.cumsum(p), q, side="right")
    assert np.array_equal(tree.find(q), expect)
    assert not np.isin(tree.find(np.array([0.0, p.sum() * (1 - 1e-16), p.sum()])), [3, 10, 11]).any()
    tree.set([5, 5], [7.0, 1.0])  # last one wins
    assert tree.get([5])[0] == 1.0
    restored = SumTree(37)
    restored.set_all(tree.leaves())
    assert restored.total == pytest.approx(tree.total)


def test_sampling_frequencies_match_priorities():
    store = make_store(capacity_transitions=64)
    fill(store, 6)  # 60 items
    rng = np.random.default_rng(1234)
    slots = np.array([ep.slots for ep in store.ring.episodes.values()]).reshape(-1)
    keys = store.priorities.slot_key[slots]
    prio = rng.uniform(0.1, 3.0, len(slots)).astype(np.float32)
    store.update_priorities(slots, keys, prio)
    n = 60_000
    counts = np.zeros(store.capacity)
    for _ in range(n // 500):
        s, *_ = store.sample(500, rng, 0.5)
        np.add.at(counts, s, 1)
    expected = np.zeros(store.capacity)
    expected[slots] = n * prio / prio.sum()
    chi2 = (((counts[slots] - expected[slots]) ** 2) / expected[slots]).sum()
    assert counts.sum() == n and counts[np.setdiff1d(np.arange(64), slots)].sum() == 0
    assert chi2 < 99.6  # chi-square, 59 degrees of freedom, p = 0.001


def test_importance_weights_match_reference_formula():
    store = make_store()
    fill(store, 3)
    slots = np.concatenate([ep.slots for ep in store.ring.episodes.values()])
    p = np.linspace(0.1, 2.0, len(slots))
    store.update_priorities(slots, store.priorities.slot_key[slots], p)
    s, k, probs, w, eps, ts = store.sample(64, np.random.default_rng(0), 0.5)
    raw = store.priorities.tree.get(s)
    ref = 1 / np.sqrt(raw + 1e-10)  # reference: w = 1/sqrt(p) / max
    assert np.allclose(w, ref / ref.max(), rtol=1e-5)
    assert np.allclose(probs, raw / store.priorities.tree.total, rtol=1e-6)


def test_new_items_get_max_priority_and_stale_updates_are_ignored():
    store = make_store(capacity_transitions=30, keep_demos=False)
    fill(store, 3)
    s, k, *_ = store.sample(5, np.random.default_rng(0), 0.5)
    assert store.update_priorities(s[:1], k[:1], [5.0]) == (1, 0)
    new = fill(store, 1, start=3)  # evicts episode 0, reuses its slots with new keys
    assert store.priorities.tree.get(store.ring.episodes[3].slots).tolist() == [5.0] * 10  # running max
    old_slots = np.arange(30)
    old_keys = np.arange(30)  # keys 0..9 were episode 0's: now stale
    applied, stale = store.update_priorities(old_slots, old_keys, np.full(30, 9.0, np.float32))
    assert stale == 10 and applied == 20
    assert store.priorities.tree.get(store.ring.episodes[3].slots).tolist() == [5.0] * 10
    assert store.counters["stale_priority_updates"] == 10
    assert store.update_priorities([1000], [0], [1.0]) == (0, 1)  # out of range: ignored
    assert new[0].episode_id == 3


def test_batch_is_bit_exact_for_every_compression():
    for comp in ("none", "lz4", "zstd"):
        store = make_store(compression=comp)
        eps = fill(store, 4, size=12, timeout=True) + fill(store, 2, actor="b", size=12, is_demo=True)
        by_key = {(actor_tag(e.actor_id), e.episode_id): e for e in eps}
        s, k, probs, w, sampled, ts = store.sample(64, np.random.default_rng(3), 0.5)
        batch = store.gather(sampled, ts)
        check_batch_exact(batch, by_key)
        assert batch["timeout"].any() and batch["is_demo"].any()


def test_n_step_transitions_reach_n_decisions_ahead_and_stop_at_the_episode_end():
    for comp in ("none", "zstd"):
        store = make_store(compression=comp, n_step=3)
        eps = fill(store, 3, size=8, steps=5) + fill(store, 1, actor="b", size=8, steps=5, timeout=True)
        by_key = {(actor_tag(e.actor_id), e.episode_id): e for e in eps}
        _, _, _, _, sampled, ts = store.sample(64, np.random.default_rng(0), 0.5)
        batch = store.gather(sampled, ts)
        assert batch["n_rewards"].shape == (64, 3)
        for i, (tag, eid, t) in enumerate(batch["extra_tag"]):
            ep = by_key[(int(tag), int(eid))]
            m = min(3, ep.num_steps - t)  # 5 steps: t = 3 sees 2 decisions, t = 4 one
            assert batch["bootstrap_steps"][i] == m
            assert tuple(batch["extra_tag_tp1"][i]) == (tag, eid, t + m)  # the observation m decisions on
            assert batch["n_rewards"][i].tolist() == [*ep.rewards[t : t + m], *[0.0] * (3 - m)]
            assert batch["reward"][i] == ep.rewards[t]
            assert batch["terminal"][i] == ep.terminals[t + m - 1]
            assert batch["timeout"][i] == (ep.timeout and t + m == ep.num_steps)
        assert set(batch["bootstrap_steps"]) == {1, 2, 3}


@pytest.mark.parametrize("n_step", [1, 3])
def test_a_gathered_batch_holds_exactly_the_transition_schema(n_step):
    """Observation arrays twice (t and ``_tp1``), then the step fields ``protocol.transition`` names, each
    with its dtype and shape; n-step fields only with n > 1."""
    store = make_store(n_step=n_step)
    episodes = fill(store, 2, size=8)
    _, _, _, _, sampled, ts = store.sample(16, np.random.default_rng(0), 0.5)
    batch = store.gather(sampled, ts)
    observed = set(episodes[0].observations)
    fields = {**transition.STEP_FIELDS, **(transition.NSTEP_FIELDS if n_step > 1 else {})}
    assert set(batch) == observed | {transition.next_name(n) for n in observed} | set(fields)
    for name, (dtype, shape, _) in fields.items():
        assert batch[name].dtype == np.dtype(dtype), name
        assert batch[name].shape == (16, *(n_step if d == "n" else d for d in shape)), name


def test_one_step_batches_carry_no_n_step_fields():
    store = make_store()
    fill(store, 2, size=8)
    _, _, _, _, sampled, ts = store.sample(8, np.random.default_rng(0), 0.5)
    assert not {"n_rewards", "bootstrap_steps"} & set(store.gather(sampled, ts))


def test_eviction_by_transitions_bytes_and_demo_keeping():
    store = make_store(capacity_transitions=50, keep_demos=True)
    fill(store, 2, actor="demo", is_demo=True)
    fill(store, 10, actor="live")
    assert store.size == 50 and store.num_episodes == 5
    assert sum(e.is_demo for e in store.ring.episodes.values()) == 2
    assert [e.episode_id for e in store.ring.episodes.values() if not e.is_demo] == [7, 8, 9]

    one = EpisodeStore(ReplayConfig(capacity_transitions=1000)).insert(synthetic_episode(size=8)).nbytes
    store = make_store(capacity_transitions=1000, capacity_bytes=int(one * 3.5), keep_demos=False)
    fill(store, 2, actor="demo", is_demo=True)
    fill(store, 4, actor="live")
    assert store.num_episodes == 3 and store.bytes <= store.config.capacity_bytes
    assert not any(e.is_demo for e in store.ring.episodes.values())  # keep_demos=False: plain FIFO


def test_duplicates_and_schema_mismatch():
    store = make_store(dedup_window=5)
    fill(store, 20)
    assert store.is_duplicate("a", 19) and not store.is_duplicate("a", 20) and not store.is_duplicate("b", 0)
    assert store.is_duplicate("a", 0)  # older than the remembered window: treated as already stored
    bad = synthetic_episode("b", 0, size=16)
    assert "do not match" in store.check(bad)
    assert "do not match" in store.check(synthetic_episode("b", 0, size=8, cameras=("front", "wrist")))
    assert store.check(synthetic_episode("b", 0, size=8)) == ""


def test_dedup_is_by_payload_digest_and_bounded():
    from replay_server.episode_dedup import _dedup_entries

    store = make_store(dedup_max_actors=2)
    store.insert(synthetic_episode("a", 0, size=8), "d1")
    assert store.is_duplicate("a", 0, "d1") and not store.is_duplicate("a", 0, "d2")
    assert store.is_id_conflict("a", 0, "d2") and not store.is_id_conflict("a", 1, "d2")
    store.insert(synthetic_episode("a", 0, size=8, timeout=True), "d2")  # another payload, same id: kept too
    assert store.is_duplicate("a", 0, "d1") and store.is_duplicate("a", 0, "d2") and store.num_episodes == 2
    assert _dedup_entries([3, [4, ["x"]]]) == {3: ("",), 4: ("x",)}  # older checkpoints held ids only
    assert store.is_duplicate("a", 0) and not store.is_duplicate("a", 1)  # no digest: by id, as before
    fill(store, 1, actor="b")
    fill(store, 1, actor="c")  # the least recently stored actor's memory goes first
    assert list(store.dedup.by_actor) == ["b", "c"]


def test_rate_limiter_holds_ratio():
    with pytest.raises(ValueError):
        RateLimiter(4.0, 10, 2.0)
    lim = RateLimiter(2.0, min_size=100, error_buffer=20)
    assert "min_size" in lim.sample_block_reason(8, size=50)
    size = 0
    for _ in range(50):  # 50 inserts of 10, sample greedily in batches of 8
        lim.inserts += 10
        size += 10
        while not lim.sample_block_reason(8, size):
            lim.samples += 8
        assert size < 100 or lim.diff >= lim.min_diff
    expected = 2.0 * (lim.inserts - 100) + 20
    assert expected - 8 <= lim.samples <= expected
    assert "waiting for inserts" in lim.sample_block_reason(8, size)
    ins = RateLimiter(1.0, min_size=10, error_buffer=16, limit_inserts=True)
    ins.inserts = 26
    assert "waiting for the learner" in ins.insert_block_reason(1)


def test_config_overrides():
    cfg = apply_overrides(ReplayConfig(), ["capacity_transitions=5000", "keep_demos=false", "seed=3",
                                           "compression=lz4", "samples_per_insert=2.5", "checkpoint_dir=none"])
    assert (cfg.capacity_transitions, cfg.keep_demos, cfg.seed, cfg.compression, cfg.samples_per_insert) == (
        5000, False, 3, "lz4", 2.5)
    with pytest.raises(ValueError):
        apply_overrides(ReplayConfig(), ["nope=1"])


# ---------------------------------------------------------------- demo share (demo and agent tables)


def mixed_store(demos=1, agents=60, **kw) -> EpisodeStore:
    """A replay like a run's: a few demo episodes among many agent ones (1 + 60 -> 1.6 % demos)."""
    kw.setdefault("capacity_transitions", 10 * (demos + agents))
    store = make_store(**kw)
    fill(store, demos, actor="demo", is_demo=True)
    fill(store, agents, actor="live")
    return store


def set_random_priorities(store, rng, low=0.1, high=3.0) -> np.ndarray:
    """Give every stored item a random priority; returns them indexed by slot."""
    slots = np.concatenate([ep.slots for ep in store.ring.episodes.values()])
    store.update_priorities(slots, store.priorities.slot_key[slots], rng.uniform(low, high, len(slots)))
    return store.priorities.tree.leaves()


def test_demo_count_rounds_and_keeps_both_tables():
    store = mixed_store()
    assert [store.priorities.demo_count(8, f) for f in (0.25, 0.01, 0.99, 1.0)] == [2, 1, 7, 8]
    assert store.priorities.demo_count(10, 0.25) == 3 and store.priorities.demo_count(128, 0.25) == 32  # round half up
    assert store.priorities.demo_count(1, 0.25) == 0 and store.priorities.demo_count(1, 0.5) == 1  # no room for both
    assert store.priorities.demo_count(8, 0.0) is None  # the reference: one table over everything
    assert make_store().priorities.demo_count(8, 0.25) is None  # nothing stored: nothing to split


def test_demo_fraction_gives_every_batch_its_demo_share():
    store = mixed_store()  # 10 demo and 600 agent transitions
    assert (store.demo_size, store.agent_size) == (10, 600)
    set_random_priorities(store, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for _ in range(200):
        s, k, probs, w, eps, ts = store.sample(8, rng, 0.5, demo_fraction=0.25)
        assert [ep.is_demo for ep in eps] == [True, True] + [False] * 6  # demo items come first
        assert store.gather(eps, ts)["is_demo"].sum() == 2
    assert store.counters["demo_transitions_sampled"] == 400
    # without a share the same replay gives demos ~1.6 % of a batch: what the option is for
    demo = [ep.is_demo for _ in range(500) for ep in store.sample(8, rng, 0.5)[4]]
    assert np.mean(demo) < 0.05


def test_demo_table_sampling_follows_priorities():
    store = mixed_store(demos=2, capacity_transitions=700)
    prio = set_random_priorities(store, np.random.default_rng(2))
    demo_slots = np.flatnonzero(store.priorities.slot_demo)
    favourite = demo_slots[7]
    store.update_priorities([favourite], store.priorities.slot_key[[favourite]], [30.0])
    prio[favourite] = 30.0
    rng = np.random.default_rng(3)
    counts = np.zeros(store.capacity)
    for _ in range(500):
        s, *_ = store.sample(64, rng, 0.5, demo_fraction=0.5)
        np.add.at(counts, s[:32], 1)  # the demo half
    n = 500 * 32
    assert counts.sum() == counts[demo_slots].sum() == n
    expected = n * prio[demo_slots] / prio[demo_slots].sum()  # p_i / total of the demo table
    chi2 = (((counts[demo_slots] - expected) ** 2) / expected).sum()
    assert chi2 < 43.8  # chi-square, 19 degrees of freedom, p = 0.001
    assert counts[favourite] > 0.3 * n  # ~30/60 of the demo draws


def test_importance_weights_are_per_table():
    store = mixed_store()
    prio = set_random_priorities(store, np.random.default_rng(4))
    s, k, probs, w, eps, ts = store.sample(64, np.random.default_rng(5), 0.5, demo_fraction=0.25)
    demo = store.priorities.slot_demo[s]
    table_total = np.where(demo, prio[store.priorities.slot_demo].sum(), prio[~store.priorities.slot_demo].sum())
    table_size = np.where(demo, store.demo_size, store.agent_size)
    assert np.allclose(probs, prio[s] / table_total, rtol=1e-6)  # P(i) within i's table
    ref = (table_size * prio[s] / table_total) ** -0.5
    assert np.allclose(w, ref / ref.max(), rtol=1e-5)
    assert (w > 0).all() and (w <= 1).all() and w.max() == 1.0


def test_demo_fraction_zero_is_the_one_table_reference():
    store = mixed_store(demos=3, agents=3)  # demos are half the replay here
    prio = set_random_priorities(store, np.random.default_rng(6))
    reference = SumTree(store.capacity)  # the old store: one tree over everything
    reference.set(np.arange(store.capacity), prio)
    s, k, probs, w, *_ = store.sample(256, np.random.default_rng(7), 0.5, demo_fraction=0.0)
    assert np.array_equal(s, reference.sample(256, np.random.default_rng(7)))  # the same draws, bit for bit
    ref_w = (store.size * prio[s] / prio.sum()) ** -0.5
    assert np.allclose(probs, prio[s] / prio.sum(), rtol=1e-6) and np.allclose(w, ref_w / ref_w.max(), rtol=1e-5)
    counts = np.zeros(store.capacity)
    rng = np.random.default_rng(8)
    for _ in range(120):
        np.add.at(counts, store.sample(500, rng, 0.5)[0], 1)
    expected = 60_000 * prio[:60] / prio[:60].sum()
    assert ((counts[:60] - expected) ** 2 / expected).sum() < 99.6  # chi-square, 59 dof, p = 0.001


def test_demo_fraction_with_only_one_kind_samples_what_exists():
    for is_demo in (True, False):
        store = make_store()
        fill(store, 3, is_demo=is_demo)
        for f in (0.25, 1.0):
            a = store.sample(8, np.random.default_rng(9), 0.5, demo_fraction=f)
            b = store.sample(8, np.random.default_rng(9), 0.5)  # the one-table draw
            assert all(ep.is_demo == is_demo for ep in a[4])
            assert all(np.array_equal(x, y) for x, y in zip(a[:4], b[:4]))


def test_evicting_agent_episodes_keeps_the_demo_table():
    store = make_store(capacity_transitions=50, keep_demos=True)
    fill(store, 1, actor="demo", is_demo=True)
    fill(store, 3, actor="live")
    demo_slots = np.flatnonzero(store.priorities.slot_demo)
    store.update_priorities(demo_slots, store.priorities.slot_key[demo_slots], np.arange(1.0, 11.0))
    demo_total = store.priorities.tables[1].total
    fill(store, 10, actor="live", start=3)  # evicts agent episodes only
    assert store.counters["episodes_evicted"] == 9 and (store.demo_size, store.agent_size) == (10, 40)
    assert store.priorities.tables[1].total == demo_total
    assert np.array_equal(np.flatnonzero(store.priorities.slot_demo), demo_slots)
    agent, demo = store.priorities.tables[0].leaves(), store.priorities.tables[1].leaves()
    assert not (agent * demo).any()  # each slot in one table
    assert np.array_equal(agent + demo, store.priorities.tree.leaves())
    eps = store.sample(8, np.random.default_rng(10), 0.5, demo_fraction=0.25)[4]
    assert sum(ep.is_demo for ep in eps) == 2
    # without keep_demos the demo episode ages out like any other, and its table empties
    plain = make_store(capacity_transitions=50, keep_demos=False)
    fill(plain, 1, actor="demo", is_demo=True)
    fill(plain, 5, actor="live")
    assert plain.demo_size == 0 and plain.priorities.tables[1].total == 0.0
    assert not any(ep.is_demo for ep in plain.sample(8, np.random.default_rng(11), 0.5, demo_fraction=0.25)[4])


def test_demo_share_survives_checkpoint_restore(tmp_path):
    store = mixed_store(compression="zstd")
    set_random_priorities(store, np.random.default_rng(12))
    store.sample(8, np.random.default_rng(13), 0.5, demo_fraction=0.25)
    restored = make_store(capacity_transitions=store.capacity, compression="zstd")
    restored.restore(load_checkpoint(write_checkpoint(tmp_path, store.snapshot()).path))
    assert (restored.demo_size, restored.agent_size) == (store.demo_size, store.agent_size)
    assert np.array_equal(restored.priorities.slot_demo, store.priorities.slot_demo)
    for mine, theirs in zip(restored.priorities.tables, store.priorities.tables):
        assert np.array_equal(mine.leaves(), theirs.leaves())
    assert restored.counters["demo_transitions_sampled"] == 2
    a = store.sample(8, np.random.default_rng(14), 0.5, demo_fraction=0.25)
    b = restored.sample(8, np.random.default_rng(14), 0.5, demo_fraction=0.25)
    assert all(np.array_equal(x, y) for x, y in zip(a[:4], b[:4]))
    assert sum(ep.is_demo for ep in b[4]) == 2


def test_demo_fraction_must_be_a_fraction():
    assert apply_overrides(ReplayConfig(), ["demo_fraction=0.25"]).demo_fraction == 0.25
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="demo_fraction must be in"):
            ReplayConfig(demo_fraction=bad)
    with pytest.raises(ValueError, match="demo_fraction must be in"):
        apply_overrides(ReplayConfig(), ["demo_fraction=2"])


# ---------------------------------------------------------------- checkpoints and WAL


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_checkpoint_restore_is_exact(tmp_path, compression):
    store = make_store(capacity_transitions=70, compression=compression, keep_demos=False)
    fill(store, 9)  # 2 evicted
    s, k, *_ = store.sample(16, np.random.default_rng(0), 0.5)
    store.update_priorities(s, k, np.random.default_rng(1).uniform(0, 3, 16).astype(np.float32))
    snap = store.snapshot()
    snap.extra = {"wal_segment": 3, "rng_state": np.random.default_rng(7).bit_generator.state}
    result = write_checkpoint(tmp_path, snap)
    restored = make_store(capacity_transitions=70, compression=compression, keep_demos=False)
    loaded = load_checkpoint(result.path)
    restored.restore(loaded)
    assert loaded.extra == json.loads(json.dumps(snap.extra))
    assert np.array_equal(restored.priorities.tree.leaves(), store.priorities.tree.leaves())
    assert np.array_equal(restored.priorities.slot_key, store.priorities.slot_key)
    for name in ("slot_serial", "slot_t"):
        assert np.array_equal(getattr(restored.ring, name), getattr(store.ring, name)), name
    assert np.array_equal(restored.ring.free[: restored.ring.n_free], store.ring.free[: store.ring.n_free])
    assert restored.counters == store.counters and restored.bytes == store.bytes
    assert (restored.priorities.next_key, restored.ring.next_serial, restored.priorities.max_priority) == (
        store.priorities.next_key, store.ring.next_serial, store.priorities.max_priority)
    assert restored.dedup.by_actor == store.dedup.by_actor and restored.schema == store.schema
    for serial, ep in store.ring.episodes.items():
        other = restored.ring.episodes[serial]
        assert other.meta() == ep.meta() and np.array_equal(other.slots, ep.slots)
        for name, a in ep.arrays.items():
            assert a.tobytes() == other.arrays[name].tobytes() and a.dtype == other.arrays[name].dtype
        assert ep.frames == other.frames
    # both stores now sample identically
    a = store.sample(8, np.random.default_rng(5), 0.5)
    b = restored.sample(8, np.random.default_rng(5), 0.5)
    assert all(np.array_equal(x, y) for x, y in zip(a[:4], b[:4]))


def test_corrupt_or_incomplete_checkpoints_are_skipped(tmp_path):
    store = make_store()
    fill(store, 2)
    first = write_checkpoint(tmp_path, store.snapshot(), keep=5)
    fill(store, 1, start=2)
    second = write_checkpoint(tmp_path, store.snapshot(), keep=5)
    (tmp_path / ".tmp-ckpt-00000009").mkdir()  # an interrupted write
    shutil.copytree(second.path, tmp_path / "ckpt-00000008")
    (tmp_path / "ckpt-00000008" / "COMPLETE").unlink()  # never completed
    path, snap = load_latest(tmp_path)
    assert path == second.path and len(snap.episodes) == 3
    with open(second.path / "slots.npy", "r+b") as f:  # flip a byte
        f.seek(-1, 2)
        b = f.read(1)
        f.seek(-1, 2)
        f.write(bytes([b[0] ^ 0xFF]))
    path, snap = load_latest(tmp_path)
    assert path == first.path and len(snap.episodes) == 2
    write_checkpoint(tmp_path, store.snapshot(), keep=2)
    assert len(list_checkpoints(tmp_path, complete_only=False)) == 2


def test_wal_replays_intact_records_and_stops_at_a_torn_tail(tmp_path):
    wal = WriteAheadLog(tmp_path, fsync=True)
    wal.append([b"one", b"two"])
    seq = wal.rotate()
    wal.append([b"three" * 1000])
    wal.close()
    with open(segment_path(tmp_path, seq), "ab") as f:
        f.write(b"WAL1\x00\x00")  # torn header
    assert list(read_segment(segment_path(tmp_path, 0))) == [b"one", b"two"]
    assert list(read_segment(segment_path(tmp_path, seq))) == [b"three" * 1000]
    with open(segment_path(tmp_path, seq), "r+b") as f:  # corrupt the payload
        f.seek(20)
        f.write(b"X")
    assert list(read_segment(segment_path(tmp_path, seq))) == []
    again = WriteAheadLog(tmp_path)
    assert again.seq == seq + 1  # never appends to an old segment
    again.delete_before(seq)
    assert list_segments(tmp_path) == [seq, seq + 1]
    again.close()


def test_batch_wire_roundtrip_and_malformed_frames():
    from protocol.codec import ProtocolError
    from protocol.messages import SampleBatch
    from protocol.sample_wire import batch_frames, parse_batch

    arrays = {"a": np.arange(12, dtype=np.float16).reshape(3, 4), "b": np.array([True, False]), "c": np.zeros((0, 2))}
    frames = [
        bytes(memoryview(f)) if isinstance(f, np.ndarray) else f
        for f in batch_frames(SampleBatch(7, arrays, "", {"x": 1.0}))
    ]
    out = parse_batch(frames)
    assert out.request_id == 7 and out.info == {"x": 1.0}
    assert all(out.arrays[k].tobytes() == v.tobytes() and out.arrays[k].shape == v.shape for k, v in arrays.items())
    for bad in (frames[:1], frames[:2] + frames[3:], [frames[0], b"{", *frames[2:]], [b"junk", *frames[1:]],
                [frames[0], frames[1], frames[2][:-1], *frames[3:]]):
        with pytest.raises(ProtocolError):
            parse_batch(bad)
