"""Which episodes were already stored: the replay's at-least-once dedup.

Actors resend an episode until it is acked, so the replay must recognise a resend. It
remembers, per actor, each stored episode id with its payload digest: an identical resend is
a duplicate, another payload under the same id is not (so nobody can suppress an actor's
episode by sending something else under its id first). Memory is bounded: the newest
``window`` ids per actor (older ids fall below a floor) and the ``max_actors`` actors that
stored most recently.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Optional

MAX_DIGESTS_PER_ID = 4  #: distinct payloads remembered under one (actor, episode id)


class EpisodeDedup:
    def __init__(self, window: int, max_actors: int):
        self.window = max(1, int(window))
        self.max_actors = max(1, int(max_actors))
        #: actor -> episode id -> payload digests stored under it; actors least recently stored first
        self.by_actor: OrderedDict[str, dict[int, tuple[str, ...]]] = OrderedDict()
        self.floor: dict[str, int] = {}  #: actor -> lowest id still remembered (once its window overflowed)

    def is_duplicate(self, actor_id: str, episode_id: int, digest: Optional[str] = None) -> bool:
        """Already stored? With a payload ``digest`` (what the service passes) only an identical
        payload is a duplicate, so nobody can suppress an actor's episode by sending another one
        under its (actor, episode id) first; ids below the remembered window are then not judged.
        Without a digest: by id alone, ids older than the window counting as stored."""
        seen = self.by_actor.get(actor_id, {})
        if digest is None:
            return episode_id < self.floor.get(actor_id, 0) or episode_id in seen
        digests = seen.get(episode_id, ())
        return digest in digests or "" in digests

    def is_id_conflict(self, actor_id: str, episode_id: int, digest: str) -> bool:
        """Another payload was already stored under this (actor, episode id): impersonation or id reuse."""
        digests = self.by_actor.get(actor_id, {}).get(episode_id, ())
        return bool(digests) and digest not in digests and "" not in digests

    def remember(self, actor_id: str, episode_id: int, digest: str = "") -> None:
        seen = self.by_actor.get(actor_id)
        if seen is None:
            seen = self.by_actor[actor_id] = {}
            while len(self.by_actor) > self.max_actors:
                forgotten, _ = self.by_actor.popitem(last=False)
                self.floor.pop(forgotten, None)
        else:
            self.by_actor.move_to_end(actor_id)
        seen[episode_id] = (seen.get(episode_id, ()) + (digest,))[-MAX_DIGESTS_PER_ID:]
        if len(seen) > 2 * self.window:
            keep = sorted(seen)[-self.window:]
            self.floor[actor_id] = keep[0]
            self.by_actor[actor_id] = {e: seen[e] for e in keep}

    def snapshot(self) -> tuple[dict[str, list], dict[str, int]]:
        """JSON-able copies for a checkpoint: ``{actor: [[id, [digests]], ...]}`` and the floors."""
        entries = {a: [[e, list(s[e])] for e in sorted(s)] for a, s in self.by_actor.items()}
        return entries, dict(self.floor)

    def restore(self, entries: dict[str, list], floor: dict[str, int]) -> None:
        self.by_actor = OrderedDict((a, _dedup_entries(ids)) for a, ids in entries.items())
        self.floor = dict(floor)


def _dedup_entries(ids: list) -> dict[int, tuple[str, ...]]:
    """A snapshot's dedup list for one actor: ``[[id, [digests]], ...]``, or plain ids (older checkpoints)."""
    out: dict[int, tuple[str, ...]] = {}
    for entry in ids:
        if isinstance(entry, (list, tuple)):
            out[int(entry[0])] = tuple(str(d) for d in entry[1])
        else:
            out[int(entry)] = ("",)
    return out
