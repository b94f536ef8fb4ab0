"""Settings of the learner process (``c2farm learner``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class LearnerConfig:
    """How the learner samples, trains, publishes and checkpoints."""

    replay_endpoint: str = ""  #: ZeroMQ endpoint of the replay's sample service; "" = replay.zmq_endpoint on this host
    batch_size: int = 128  #: transitions per update (the paper's 128; the cpu-small preset uses 8)
    prefetch: int = 2  #: sample requests kept in flight so the learner never waits on a round trip
    device: str = "auto"  #: "auto" (CUDA when present), "cpu" or "cuda[:N]"
    torch_threads: int = 1  #: intra-op threads on CPU (leave cores for the actors)
    max_updates: int = 0  #: stop after this many update() calls; 0 = run until stopped
    publish_every: int = 10  #: broadcast weights every this many updates
    checkpoint_every: int = 200  #: checkpoint every this many updates (and on stop)
    checkpoint_keep: int = 2  #: complete checkpoints kept on disk
    log_every: int = 10  #: write a metrics row (CSV + TensorBoard) every this many updates
    sample_timeout_s: float = 30.0  #: longest wait for one batch before logging why and asking again
    tensorboard: bool = True  #: also write TensorBoard scalars under runs/<id>/tensorboard
    acting_average: float = 0.0  #: publish an EMA of the online weights (this decay per update) for acting and evaluation; 0 = the online weights (reference)
