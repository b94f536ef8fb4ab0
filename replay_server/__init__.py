"""The replay server role: episode-structured prioritised replay behind Zenoh (ingest) and
ZeroMQ (samples). Needs ``protocol/`` and numpy; never torch."""

from replay_server.config import ReplayConfig

__all__ = ["ReplayConfig"]
