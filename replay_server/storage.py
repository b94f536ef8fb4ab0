"""The replay's store: what the ingest, sample and checkpoint threads call, composing its parts.

- :mod:`replay_server.stored_episode`: an episode's in-memory form and the schema check;
- :mod:`replay_server.episode_ring`: the slots, the stored episodes and eviction;
- :mod:`replay_server.prioritised_tables`: priorities, keys and sampling (demo and agent tables);
- :mod:`replay_server.transition_batch`: sampled items -> the learner's batch (n-step);
- :mod:`replay_server.episode_dedup`: which episodes were already stored.

This class keeps them in step (an evicted episode's slots leave the tables, a restored one
re-enters both), owns the counters and makes one :class:`Snapshot` of all of them.

Not thread-safe: the service guards a store with one lock. Stored arrays are never
mutated after insertion, so a snapshot may hold references to them without copying.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Optional

import numpy as np

from protocol.episode import Episode
from replay_server.config import ReplayConfig
from replay_server.episode_dedup import EpisodeDedup
from replay_server.episode_ring import EpisodeRing
from replay_server.frame_codec import FrameCodec
from replay_server.prioritised_tables import PrioritisedTables
from replay_server.stored_episode import Schema, StoredEpisode, episode_schema, pack_episode
from replay_server.transition_batch import gather_transitions


@dataclass
class Snapshot:
    """A consistent, cheap (reference-holding) copy of a store, for checkpointing."""

    episodes: list[StoredEpisode]
    schema: Optional[Schema]
    compression: str
    priorities: np.ndarray  #: float64 [capacity]; a slot's table follows from its episode's is_demo
    slot_key: np.ndarray  #: int64 [capacity]
    free: np.ndarray  #: int64 free-slot stack
    state: dict  #: scalars: next_key, next_serial, max_priority, counters
    dedup: dict[str, list]  #: actor -> [[episode id, [payload digests]], ...] ("" digest: id-only, old checkpoints)
    dedup_floor: dict[str, int]
    extra: dict = field(default_factory=dict)  #: filled by the service (rate limiter, rng, wal segment)


class SampledItems(NamedTuple):
    """One batch's items as :meth:`EpisodeStore.sample` draws them (length B each, in draw order).

    A tuple, so ``slots, keys, probabilities, weights, episodes, ts = store.sample(...)`` works.
    """

    slots: np.ndarray  #: int64: the slot of each item (the learner's ``indices``)
    keys: np.ndarray  #: int64: each item's key, to send back with its new priority
    probabilities: np.ndarray  #: float32: P(i) within the table it was drawn from
    weights: np.ndarray  #: float32: importance weights, normalised by the batch max
    episodes: list[StoredEpisode]  #: the episode each item belongs to
    ts: np.ndarray  #: int32: each item's transition index in its episode


class EpisodeStore:
    def __init__(self, config: ReplayConfig):
        self.config = config
        cap = int(config.capacity_transitions)
        if cap < 1:
            raise ValueError("capacity_transitions must be >= 1")
        self.capacity = cap
        self.codec = FrameCodec(config.compression, config.zstd_level)
        self.ring = EpisodeRing(cap, config.capacity_bytes, config.keep_demos)
        self.priorities = PrioritisedTables(cap, config.initial_priority, config.priority_alpha, config.priority_eps)
        self.dedup = EpisodeDedup(config.dedup_window, config.dedup_max_actors)
        self.schema: Optional[Schema] = None  #: what every stored episode's observations are (set by the first)
        self.counters = {
            "episodes_stored": 0,
            "transitions_inserted": 0,
            "episodes_evicted": 0,
            "transitions_sampled": 0,
            "demo_transitions_sampled": 0,
            "priority_updates": 0,
            "stale_priority_updates": 0,
        }

    # ------------------------------------------------------------------ size
    @property
    def size(self) -> int:
        """Stored transitions (items)."""
        return self.ring.size

    @property
    def demo_size(self) -> int:
        """Stored transitions of demo episodes."""
        return self.priorities.demo_size

    @property
    def agent_size(self) -> int:
        """Stored transitions of agent (non-demo) episodes."""
        return self.size - self.demo_size

    @property
    def num_episodes(self) -> int:
        return len(self.ring.episodes)

    @property
    def bytes(self) -> int:
        return self.ring.bytes

    # ------------------------------------------------------------------ dedup
    def is_duplicate(self, actor_id: str, episode_id: int, digest: Optional[str] = None) -> bool:
        """See :meth:`EpisodeDedup.is_duplicate`."""
        return self.dedup.is_duplicate(actor_id, episode_id, digest)

    def is_id_conflict(self, actor_id: str, episode_id: int, digest: str) -> bool:
        """See :meth:`EpisodeDedup.is_id_conflict`."""
        return self.dedup.is_id_conflict(actor_id, episode_id, digest)

    # ------------------------------------------------------------------ insert
    def check(self, episode: Episode) -> str:
        """Why ``episode`` can never be stored here (empty string if it can)."""
        if episode.num_steps > self.capacity:
            return f"episode has {episode.num_steps} steps, more than capacity_transitions={self.capacity}"
        schema = episode_schema(episode, self.config.points_float16)
        if self.schema is not None and schema != self.schema:
            diff = sorted(set(schema.items()) ^ set(self.schema.items()))
            return f"observation arrays do not match what this replay stores: {diff[:4]}"
        return ""

    def insert(self, episode: Episode, digest: str = "") -> StoredEpisode:
        """Store a validated, non-duplicate episode that passed :meth:`check` (``digest``: its payload's)."""
        reason = self.check(episode)
        if reason:
            raise ValueError(reason)
        stored = pack_episode(episode, self.ring.next_serial, self.codec, self.config.points_float16)
        if stored.nbytes > self.config.capacity_bytes:
            raise ValueError(f"episode needs {stored.nbytes} bytes, more than capacity_bytes")
        evicted = self.ring.insert(stored)
        for ep in evicted:
            self.priorities.remove(ep.slots, ep.is_demo)
        self.priorities.add(stored.slots, stored.is_demo)
        self.counters["episodes_evicted"] += len(evicted)
        if self.schema is None:
            self.schema = episode_schema(episode, self.config.points_float16)
        self.dedup.remember(stored.actor_id, stored.episode_id, digest)
        self.counters["episodes_stored"] += 1
        self.counters["transitions_inserted"] += stored.num_steps
        return stored

    # ------------------------------------------------------------------ sample
    def sample(
        self, batch_size: int, rng: np.random.Generator, beta: float, demo_fraction: float = 0.0
    ) -> SampledItems:
        """Draw ``batch_size`` items (see :meth:`PrioritisedTables.sample` for the distribution)."""
        draw = self.priorities.sample(batch_size, rng, beta, demo_fraction)
        episodes, ts = self.ring.lookup(draw.slots)
        self.counters["transitions_sampled"] += batch_size
        self.counters["demo_transitions_sampled"] += int(self.priorities.slot_demo[draw.slots].sum())
        return SampledItems(*draw, episodes, ts)

    def gather(self, episodes: list[StoredEpisode], ts: np.ndarray) -> dict[str, np.ndarray]:
        """The batch arrays of sampled items (may run without the store lock: episodes are immutable)."""
        assert self.schema is not None
        return gather_transitions(episodes, ts, self.schema, self.codec, self.config.n_step)

    def update_priorities(self, indices: np.ndarray, keys: np.ndarray, priorities: np.ndarray) -> tuple[int, int]:
        """Apply updates whose key still matches the slot; returns (applied, stale)."""
        applied, stale = self.priorities.update(indices, keys, priorities)
        self.counters["priority_updates"] += applied
        self.counters["stale_priority_updates"] += stale
        return applied, stale

    # ------------------------------------------------------------------ snapshot / restore
    def snapshot(self) -> Snapshot:
        dedup, dedup_floor = self.dedup.snapshot()
        return Snapshot(
            episodes=self.ring.in_order(),
            schema=None if self.schema is None else dict(self.schema),
            compression=self.codec.kind,
            priorities=self.priorities.tree.leaves(),
            slot_key=self.priorities.slot_key.copy(),
            free=self.ring.free[: self.ring.n_free].copy(),
            state={
                "next_key": self.priorities.next_key,
                "next_serial": self.ring.next_serial,
                "max_priority": self.priorities.max_priority,
                "counters": dict(self.counters),
                "capacity_transitions": self.capacity,
            },
            dedup=dedup,
            dedup_floor=dedup_floor,
        )

    def restore(self, snap: Snapshot) -> None:
        """Load a snapshot into an empty store with the same capacity and compression."""
        if self.ring.episodes:
            raise RuntimeError("restore needs an empty store")
        if snap.state["capacity_transitions"] != self.capacity:
            raise ValueError(
                f"checkpoint capacity {snap.state['capacity_transitions']} != configured {self.capacity}"
            )
        if snap.compression != self.codec.kind:
            raise ValueError(f"checkpoint compression {snap.compression!r} != configured {self.codec.kind!r}")
        self.schema = None if snap.schema is None else dict(snap.schema)
        self.ring.restore(snap.episodes, snap.free)
        for ep in snap.episodes:
            self.priorities.add(ep.slots, ep.is_demo, snap.priorities[ep.slots], snap.slot_key[ep.slots])
        self.priorities.next_key = int(snap.state["next_key"])
        self.ring.next_serial = int(snap.state["next_serial"])
        self.priorities.max_priority = float(snap.state["max_priority"])
        self.counters.update({k: int(v) for k, v in snap.state["counters"].items()})
        self.dedup.restore(snap.dedup, snap.dedup_floor)
        if self.size != sum(ep.num_steps for ep in snap.episodes):
            raise ValueError("checkpoint free list does not match its episodes")
