"""Episode-structured prioritised storage.

Each episode is kept whole: its ``T + 1`` observations are stored once, and transition ``t``
references observations ``t`` and ``t + 1`` of the same episode. Transitions are *items*:
each occupies one slot of the sum tree, carries a unique, never reused ``key`` (so a
priority update for a slot that has since been overwritten is ignored), and points back to
``(episode, t)``. Capacity is bounded in transitions (slots) and in bytes; the oldest
episode is evicted first (demos last, if ``keep_demos``).

Two tables, demo and agent, share the slot space: each slot's priority also sits in the sum
tree of its episode's kind, so :meth:`EpisodeStore.sample` can give demos a fixed share of
every batch (``demo_fraction``). Ten demos (~130 keyframe transitions) are ~1 % of a full
replay, so proportional sampling alone draws them into ~1 % of each batch. With
``demo_fraction = 0`` sampling is the reference's: one proportional distribution over every
item, from the combined tree.

Large per-camera arrays (``*_rgb``, ``*_points``) can be compressed per frame (lz4/zstd),
so sampling one transition decompresses exactly two frames per array.

Dedup remembers, per actor, each stored episode id with its payload digest: an identical
resend is a duplicate, another payload under the same id is not (so nobody can suppress an
actor's episode by sending something else under its id first).

Not thread-safe: the service guards a store with one lock. Stored arrays are never
mutated after insertion, so a snapshot may hold references to them without copying.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from protocol.episode import Episode
from replay_server.config import ReplayConfig
from replay_server.sumtree import SumTree

STEP_NAMES = ("actions", "rewards", "terminals", "policy_versions")
COMPRESSIBLE_SUFFIXES = ("_rgb", "_points")
MAX_DIGESTS_PER_ID = 4  #: distinct payloads remembered under one (actor, episode id)


class FrameCodec:
    """Per-frame compression; compressor objects are kept per thread (zstd's are not thread-safe)."""

    def __init__(self, kind: str = "none", level: int = 1):
        if kind not in ("none", "lz4", "zstd"):
            raise ValueError(f"unknown compression {kind!r}")
        self.kind, self.level = kind, level
        self._local = threading.local()

    @property
    def enabled(self) -> bool:
        return self.kind != "none"

    def compress(self, frame: np.ndarray) -> bytes:
        data = np.ascontiguousarray(frame).reshape(-1).view(np.uint8)
        if self.kind == "lz4":
            import lz4.block

            return lz4.block.compress(data, store_size=True)
        c = getattr(self._local, "c", None)
        if c is None:
            import zstandard

            c = self._local.c = zstandard.ZstdCompressor(level=self.level)
        return c.compress(data)

    def decompress_into(self, blob: bytes, out: np.ndarray) -> None:
        if self.kind == "lz4":
            import lz4.block

            raw = lz4.block.decompress(blob)
        else:
            d = getattr(self._local, "d", None)
            if d is None:
                import zstandard

                d = self._local.d = zstandard.ZstdDecompressor()
            raw = d.decompress(blob)
        out.reshape(-1).view(np.uint8)[:] = np.frombuffer(raw, dtype=np.uint8)


@dataclass(eq=False)
class StoredEpisode:
    """One episode as kept in memory (immutable once inserted)."""

    serial: int  #: insertion order, unique within a store
    actor_id: str
    episode_id: int
    task: str
    seed: int
    is_demo: bool
    success: bool
    timeout: bool
    info: dict[str, str]
    num_steps: int
    arrays: dict[str, np.ndarray]  #: observation names (uncompressed) and "step/<name>" arrays
    frames: dict[str, list[bytes]]  #: compressed observation names: one blob per observation
    slots: np.ndarray  #: int64 [T]: the slot of transition t
    nbytes: int

    def meta(self) -> dict:
        return {
            "serial": self.serial,
            "actor_id": self.actor_id,
            "episode_id": self.episode_id,
            "task": self.task,
            "seed": self.seed,
            "is_demo": self.is_demo,
            "success": self.success,
            "timeout": self.timeout,
            "info": self.info,
            "num_steps": self.num_steps,
        }


@dataclass
class Snapshot:
    """A consistent, cheap (reference-holding) copy of a store, for checkpointing."""

    episodes: list[StoredEpisode]
    schema: Optional[dict[str, tuple[str, tuple[int, ...]]]]
    compression: str
    priorities: np.ndarray  #: float64 [capacity]; a slot's table follows from its episode's is_demo
    slot_key: np.ndarray  #: int64 [capacity]
    free: np.ndarray  #: int64 free-slot stack
    state: dict  #: scalars: next_key, next_serial, max_priority, counters
    dedup: dict[str, list]  #: actor -> [[episode id, [payload digests]], ...] ("" digest: id-only, old checkpoints)
    dedup_floor: dict[str, int]
    extra: dict = field(default_factory=dict)  #: filled by the service (rate limiter, rng, wal segment)


class EpisodeStore:
    def __init__(self, config: ReplayConfig):
        self.config = config
        cap = int(config.capacity_transitions)
        if cap < 1:
            raise ValueError("capacity_transitions must be >= 1")
        self.capacity = cap
        self.codec = FrameCodec(config.compression, config.zstd_level)
        self.tree = SumTree(cap)  #: every item: the one-table (reference) distribution; what snapshots store
        self.tables = (SumTree(cap), SumTree(cap))  #: (agent, demo): each slot's priority, in its kind's tree only
        self.slot_demo = np.zeros(cap, dtype=bool)  #: which table a slot belongs to
        self.demo_size = 0  #: stored demo transitions (the agent table holds size - demo_size)
        self.slot_serial = np.full(cap, -1, dtype=np.int64)
        self.slot_t = np.zeros(cap, dtype=np.int32)
        self.slot_key = np.full(cap, -1, dtype=np.int64)
        self.free = np.arange(cap - 1, -1, -1, dtype=np.int64)  # a stack: pop from the end -> 0, 1, 2...
        self.n_free = cap
        self.episodes: dict[int, StoredEpisode] = {}
        self._fifo_live: OrderedDict[int, None] = OrderedDict()
        self._fifo_demo: OrderedDict[int, None] = OrderedDict()
        self.schema: Optional[dict[str, tuple[str, tuple[int, ...]]]] = None
        self.next_key = 0
        self.next_serial = 0
        self.max_priority = float(config.initial_priority)
        self.bytes = 0
        #: actor -> episode id -> payload digests stored under it; actors least recently stored first
        self.dedup: OrderedDict[str, dict[int, tuple[str, ...]]] = OrderedDict()
        self.dedup_floor: dict[str, int] = {}
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
        return self.capacity - self.n_free

    @property
    def agent_size(self) -> int:
        """Stored transitions of agent (non-demo) episodes."""
        return self.size - self.demo_size

    @property
    def num_episodes(self) -> int:
        return len(self.episodes)

    def _set_priorities(self, slots: np.ndarray, values) -> None:
        """Write priorities to the combined tree and to each slot's own table."""
        slots = np.asarray(slots, dtype=np.int64).reshape(-1)
        values = np.broadcast_to(np.asarray(values, dtype=np.float64), slots.shape)
        self.tree.set(slots, values)
        demo = self.slot_demo[slots]
        for kind, tree in enumerate(self.tables):
            mask = demo == bool(kind)
            tree.set(slots[mask], values[mask])

    # ------------------------------------------------------------------ dedup
    def is_duplicate(self, actor_id: str, episode_id: int, digest: Optional[str] = None) -> bool:
        """Already stored? With a payload ``digest`` (what the service passes) only an identical
        payload is a duplicate, so nobody can suppress an actor's episode by sending another one
        under its (actor, episode id) first; ids below the remembered window are then not judged.
        Without a digest: by id alone, ids older than the window counting as stored."""
        seen = self.dedup.get(actor_id, {})
        if digest is None:
            return episode_id < self.dedup_floor.get(actor_id, 0) or episode_id in seen
        digests = seen.get(episode_id, ())
        return digest in digests or "" in digests

    def is_id_conflict(self, actor_id: str, episode_id: int, digest: str) -> bool:
        """Another payload was already stored under this (actor, episode id): impersonation or id reuse."""
        digests = self.dedup.get(actor_id, {}).get(episode_id, ())
        return bool(digests) and digest not in digests and "" not in digests

    def _remember(self, actor_id: str, episode_id: int, digest: str = "") -> None:
        seen = self.dedup.get(actor_id)
        if seen is None:
            seen = self.dedup[actor_id] = {}
            while len(self.dedup) > max(1, int(self.config.dedup_max_actors)):
                forgotten, _ = self.dedup.popitem(last=False)
                self.dedup_floor.pop(forgotten, None)
        else:
            self.dedup.move_to_end(actor_id)
        seen[episode_id] = (seen.get(episode_id, ()) + (digest,))[-MAX_DIGESTS_PER_ID:]
        window = max(1, int(self.config.dedup_window))
        if len(seen) > 2 * window:
            keep = sorted(seen)[-window:]
            self.dedup_floor[actor_id] = keep[0]
            self.dedup[actor_id] = {e: seen[e] for e in keep}

    # ------------------------------------------------------------------ insert
    def _stored_dtype(self, name: str, array: np.ndarray) -> np.dtype:
        if name.endswith("_points") and self.config.points_float16 and array.dtype == np.float32:
            return np.dtype(np.float16)
        return array.dtype

    def episode_schema(self, episode: Episode) -> dict[str, tuple[str, tuple[int, ...]]]:
        return {
            name: (self._stored_dtype(name, a).name, tuple(int(s) for s in a.shape[1:]))
            for name, a in sorted(episode.observations.items())
        }

    def check(self, episode: Episode) -> str:
        """Why ``episode`` can never be stored here (empty string if it can)."""
        if episode.num_steps > self.capacity:
            return f"episode has {episode.num_steps} steps, more than capacity_transitions={self.capacity}"
        schema = self.episode_schema(episode)
        if self.schema is not None and schema != self.schema:
            diff = sorted(set(schema.items()) ^ set(self.schema.items()))
            return f"observation arrays do not match what this replay stores: {diff[:4]}"
        return ""

    def _pack(self, episode: Episode, serial: int) -> StoredEpisode:
        arrays: dict[str, np.ndarray] = {}
        frames: dict[str, list[bytes]] = {}
        nbytes = 0
        for name, a in episode.observations.items():
            dtype = self._stored_dtype(name, a)
            if dtype != a.dtype:
                a = a.astype(dtype)
            if self.codec.enabled and name.endswith(COMPRESSIBLE_SUFFIXES):
                blobs = [self.codec.compress(f) for f in a]
                frames[name] = blobs
                nbytes += sum(len(b) for b in blobs)
            else:
                arrays[name] = a
                nbytes += a.nbytes
        for name in STEP_NAMES:
            a = getattr(episode, name)
            arrays["step/" + name] = a
            nbytes += a.nbytes
        return StoredEpisode(
            serial=serial,
            actor_id=episode.actor_id,
            episode_id=int(episode.episode_id),
            task=episode.task,
            seed=int(episode.seed),
            is_demo=bool(episode.is_demo),
            success=bool(episode.success),
            timeout=bool(episode.timeout),
            info=dict(episode.info),
            num_steps=episode.num_steps,
            arrays=arrays,
            frames=frames,
            slots=np.empty(0, dtype=np.int64),
            nbytes=nbytes,
        )

    def insert(self, episode: Episode, digest: str = "") -> StoredEpisode:
        """Store a validated, non-duplicate episode that passed :meth:`check` (``digest``: its payload's)."""
        reason = self.check(episode)
        if reason:
            raise ValueError(reason)
        stored = self._pack(episode, self.next_serial)
        if stored.nbytes > self.config.capacity_bytes:
            raise ValueError(f"episode needs {stored.nbytes} bytes, more than capacity_bytes")
        self._add(stored)
        if self.schema is None:
            self.schema = self.episode_schema(episode)
        self._remember(stored.actor_id, stored.episode_id, digest)
        self.counters["episodes_stored"] += 1
        self.counters["transitions_inserted"] += stored.num_steps
        return stored

    def _add(self, stored: StoredEpisode, slots: Optional[np.ndarray] = None, priorities=None, keys=None) -> None:
        t_steps = stored.num_steps
        if slots is None:
            while self.n_free < t_steps or self.bytes + stored.nbytes > self.config.capacity_bytes:
                self._evict_one()
            slots = self.free[self.n_free - t_steps : self.n_free][::-1].copy()
            self.n_free -= t_steps
            keys = np.arange(self.next_key, self.next_key + t_steps, dtype=np.int64)
            self.next_key += t_steps
            priorities = np.full(t_steps, self.max_priority)
        stored.slots = slots
        self.next_serial = max(self.next_serial, stored.serial + 1)
        self.episodes[stored.serial] = stored
        (self._fifo_demo if stored.is_demo else self._fifo_live)[stored.serial] = None
        self.bytes += stored.nbytes
        self.slot_serial[slots] = stored.serial
        self.slot_t[slots] = np.arange(t_steps, dtype=np.int32)
        self.slot_key[slots] = keys
        self.slot_demo[slots] = stored.is_demo
        self.demo_size += t_steps if stored.is_demo else 0
        self._set_priorities(slots, priorities)

    def _evict_one(self) -> None:
        if self.config.keep_demos:
            fifo = self._fifo_live if self._fifo_live else self._fifo_demo
        else:
            heads = [f for f in (self._fifo_live, self._fifo_demo) if f]
            fifo = min(heads, key=lambda f: next(iter(f))) if heads else self._fifo_live
        if not fifo:
            raise RuntimeError("nothing left to evict")  # guarded by check(): cannot happen
        serial, _ = fifo.popitem(last=False)
        ep = self.episodes.pop(serial)
        self.bytes -= ep.nbytes
        self._set_priorities(ep.slots, 0.0)
        self.slot_demo[ep.slots] = False
        self.demo_size -= ep.num_steps if ep.is_demo else 0
        self.slot_serial[ep.slots] = -1
        self.slot_key[ep.slots] = -1
        self.free[self.n_free : self.n_free + len(ep.slots)] = ep.slots[::-1]
        self.n_free += len(ep.slots)
        self.counters["episodes_evicted"] += 1

    # ------------------------------------------------------------------ sample
    def demo_count(self, batch_size: int, demo_fraction: float) -> Optional[int]:
        """How many items of a batch come from the demo table; None: one table over everything.

        ``round(demo_fraction * batch_size)`` (halves up), but at least one item from each
        table when ``0 < demo_fraction < 1`` and the batch has room for both, so that neither
        kind silently vanishes from a small batch. None (the reference's one proportional
        table) when the fraction is 0 or either table has nothing to sample: a batch then
        comes from whatever exists.
        """
        if demo_fraction <= 0 or self.tables[0].total <= 0 or self.tables[1].total <= 0:
            return None
        if demo_fraction >= 1:
            return batch_size
        n = math.floor(demo_fraction * batch_size + 0.5)
        return min(max(n, 1), batch_size - 1) if batch_size >= 2 else n

    def sample(self, batch_size: int, rng: np.random.Generator, beta: float, demo_fraction: float = 0.0):
        """Draw ``batch_size`` items; returns (slots, keys, probabilities, weights, episodes, ts).

        With a demo share (see :meth:`demo_count`) the first ``n_demo`` items come from the
        demo table and the rest from the agent table, each proportionally to priority within
        its table: ``P(i) = p_i / total of i's table`` and ``w = (N_table * P(i)) ** -beta``,
        normalised by the batch max. Otherwise one table over all ``N`` items (the reference).
        """
        n_demo = self.demo_count(batch_size, demo_fraction)
        if n_demo is None:
            slots = self.tree.sample(batch_size, rng)
            probs = self.tree.get(slots) / self.tree.total
            n_items = np.full(batch_size, float(max(1, self.size)))
        else:
            demo, agent = self.tables[1], self.tables[0]
            d_slots, a_slots = demo.sample(n_demo, rng), agent.sample(batch_size - n_demo, rng)
            slots = np.concatenate([d_slots, a_slots])
            probs = np.concatenate([demo.get(d_slots) / demo.total, agent.get(a_slots) / agent.total])
            n_items = np.repeat([float(self.demo_size), float(self.agent_size)], [len(d_slots), len(a_slots)])
        with np.errstate(divide="ignore"):
            w = np.power(n_items * probs, -beta) if beta else np.ones_like(probs)
        w = w / w.max()
        serials = self.slot_serial[slots]
        if (serials < 0).any():
            raise RuntimeError("sampled an empty slot")  # find() never returns a zero leaf
        episodes = [self.episodes[int(s)] for s in serials]
        self.counters["transitions_sampled"] += batch_size
        self.counters["demo_transitions_sampled"] += int(self.slot_demo[slots].sum())
        return (
            slots.astype(np.int64),
            self.slot_key[slots].copy(),
            probs.astype(np.float32),
            w.astype(np.float32),
            episodes,
            self.slot_t[slots].copy(),
        )

    def gather(self, episodes: list[StoredEpisode], ts: np.ndarray) -> dict[str, np.ndarray]:
        """Build the batch arrays (may run without the store lock: episodes are immutable).

        With ``n_step`` = n > 1 each row is an n-step transition: ``*_tp1`` is the observation
        m = min(n, T - t) decisions later, ``rewards`` [B, n] the rewards in between (zeros past
        the episode's end), ``bootstrap_steps`` [B] that m, and ``terminal``/``timeout`` those of
        step t + m - 1; ``reward`` stays step t's own. The learner discounts with its gamma.
        """
        b = len(episodes)
        n = int(self.config.n_step)
        ts = np.asarray(ts, dtype=np.int64)
        steps = np.array([min(n, ep.num_steps - t) for ep, t in zip(episodes, ts)], dtype=np.int64)
        nxt_t = ts + steps
        last = nxt_t - 1  # the step whose terminal/timeout flags end this transition
        out: dict[str, np.ndarray] = {}
        assert self.schema is not None
        for name, (dtype, shape) in self.schema.items():
            cur = np.empty((b,) + shape, dtype=dtype)
            nxt = np.empty((b,) + shape, dtype=dtype)
            if episodes[0].frames and name in episodes[0].frames:
                for i, (ep, t, t1) in enumerate(zip(episodes, ts, nxt_t)):
                    blobs = ep.frames[name]
                    self.codec.decompress_into(blobs[t], cur[i])
                    self.codec.decompress_into(blobs[t1], nxt[i])
            else:
                for i, (ep, t, t1) in enumerate(zip(episodes, ts, nxt_t)):
                    a = ep.arrays[name]
                    cur[i] = a[t]
                    nxt[i] = a[t1]
            out[name] = cur
            out[name + "_tp1"] = nxt
        out["action"] = np.stack([ep.arrays["step/actions"][t] for ep, t in zip(episodes, ts)])
        out["reward"] = np.array([ep.arrays["step/rewards"][t] for ep, t in zip(episodes, ts)], dtype=np.float32)
        out["terminal"] = np.array([ep.arrays["step/terminals"][t] for ep, t in zip(episodes, last)], dtype=bool)
        out["timeout"] = np.array([ep.timeout and t == ep.num_steps - 1 for ep, t in zip(episodes, last)], dtype=bool)
        if n > 1:
            rewards = np.zeros((b, n), dtype=np.float32)
            for i, (ep, t, m) in enumerate(zip(episodes, ts, steps)):
                rewards[i, :m] = ep.arrays["step/rewards"][t : t + m]
            out["rewards"] = rewards
            out["bootstrap_steps"] = steps
        out["policy_version"] = np.array(
            [ep.arrays["step/policy_versions"][t] for ep, t in zip(episodes, ts)], dtype=np.int64
        )
        out["is_demo"] = np.array([ep.is_demo for ep in episodes], dtype=bool)
        return out

    # ------------------------------------------------------------------ priorities
    def update_priorities(self, indices: np.ndarray, keys: np.ndarray, priorities: np.ndarray) -> tuple[int, int]:
        """Apply updates whose key still matches the slot; returns (applied, stale)."""
        indices = np.asarray(indices, dtype=np.int64)
        keys = np.asarray(keys, dtype=np.int64)
        p = np.asarray(priorities, dtype=np.float64)
        in_range = (indices >= 0) & (indices < self.capacity)
        ok = in_range.copy()
        ok[in_range] = self.slot_key[indices[in_range]] == keys[in_range]
        ok &= self.slot_key[np.where(in_range, indices, 0)] >= 0
        ok &= np.isfinite(p) & (p >= 0)
        applied = int(ok.sum())
        if applied:
            vals = np.maximum(np.power(p[ok], self.config.priority_alpha), self.config.priority_eps)
            self._set_priorities(indices[ok], vals)
            self.max_priority = max(self.max_priority, float(vals.max()))
        stale = len(indices) - applied
        self.counters["priority_updates"] += applied
        self.counters["stale_priority_updates"] += stale
        return applied, stale

    # ------------------------------------------------------------------ snapshot / restore
    def snapshot(self) -> Snapshot:
        return Snapshot(
            episodes=list(self.episodes[s] for s in sorted(self.episodes)),
            schema=None if self.schema is None else dict(self.schema),
            compression=self.codec.kind,
            priorities=self.tree.leaves(),
            slot_key=self.slot_key.copy(),
            free=self.free[: self.n_free].copy(),
            state={
                "next_key": self.next_key,
                "next_serial": self.next_serial,
                "max_priority": self.max_priority,
                "counters": dict(self.counters),
                "capacity_transitions": self.capacity,
            },
            dedup={a: [[e, list(s[e])] for e in sorted(s)] for a, s in self.dedup.items()},
            dedup_floor=dict(self.dedup_floor),
        )

    def restore(self, snap: Snapshot) -> None:
        """Load a snapshot into an empty store with the same capacity and compression."""
        if self.episodes:
            raise RuntimeError("restore needs an empty store")
        if snap.state["capacity_transitions"] != self.capacity:
            raise ValueError(
                f"checkpoint capacity {snap.state['capacity_transitions']} != configured {self.capacity}"
            )
        if snap.compression != self.codec.kind:
            raise ValueError(f"checkpoint compression {snap.compression!r} != configured {self.codec.kind!r}")
        self.schema = None if snap.schema is None else dict(snap.schema)
        for ep in snap.episodes:
            self._add(ep, slots=ep.slots, priorities=snap.priorities[ep.slots], keys=snap.slot_key[ep.slots])
        self.n_free = len(snap.free)
        self.free[: self.n_free] = snap.free
        self.next_key = int(snap.state["next_key"])
        self.next_serial = int(snap.state["next_serial"])
        self.max_priority = float(snap.state["max_priority"])
        self.counters.update({k: int(v) for k, v in snap.state["counters"].items()})
        self.dedup = OrderedDict((a, _dedup_entries(ids)) for a, ids in snap.dedup.items())
        self.dedup_floor = dict(snap.dedup_floor)
        if self.size != sum(ep.num_steps for ep in snap.episodes):
            raise ValueError("checkpoint free list does not match its episodes")


def _dedup_entries(ids: list) -> dict[int, tuple[str, ...]]:
    """A snapshot's dedup list for one actor: ``[[id, [digests]], ...]``, or plain ids (older checkpoints)."""
    out: dict[int, tuple[str, ...]] = {}
    for entry in ids:
        if isinstance(entry, (list, tuple)):
            out[int(entry[0])] = tuple(str(d) for d in entry[1])
        else:
            out[int(entry)] = ("",)
    return out
