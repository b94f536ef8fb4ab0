"""Settings of the learner process (``c2farm learner``)."""

from __future__ import annotations

import re
from dataclasses import dataclass

from protocol.config_checks import above, at_least, within, zmq_endpoint
from protocol.zmq_curve import check_pair

#: What ``device`` accepts (learner.train.resolve_device hands it to torch.device).
_DEVICE = re.compile(r"auto|cpu|mps|cuda(:\d+)?")


@dataclass
class LearnerConfig:
    """How the learner samples, trains, publishes and checkpoints."""

    #: ZeroMQ endpoint of the replay's sample service (tcp://HOST:PORT); "" = replay.zmq_endpoint on this host
    replay_endpoint: str = ""
    #: transitions per update, >= 1 and <= replay.max_batch_size (the paper's 128; the cpu-small preset uses 8)
    batch_size: int = 128
    prefetch: int = 2  #: sample requests kept in flight so the learner never waits on a round trip, >= 1
    device: str = "auto"  #: "auto" (CUDA when present), "cpu", "mps" or "cuda[:N]"
    torch_threads: int = 1  #: intra-op threads on CPU (leave cores for the actors), >= 1
    max_updates: int = 0  #: stop after this many update() calls, >= 0; 0 = run until stopped
    publish_every: int = 10  #: broadcast weights every this many updates, >= 1
    checkpoint_every: int = 200  #: checkpoint every this many updates (and on stop), >= 1
    #: also checkpoint once this many seconds have passed since the last one (>= 0; 0 = by updates only), so a killed
    #: learner loses at most this much training however slow its updates are
    checkpoint_every_s: float = 120.0
    checkpoint_keep: int = 2  #: complete checkpoints kept on disk, >= 1
    log_every: int = 10  #: write a metrics row (CSV + TensorBoard) every this many updates, >= 1
    sample_timeout_s: float = 30.0  #: longest wait for one batch before logging why and asking again, > 0
    tensorboard: bool = True  #: also write TensorBoard scalars under runs/<id>/tensorboard
    #: publish an EMA of the online weights (this decay per update, in [0, 1)) for acting and evaluation; 0 = the online
    #: weights (reference)
    acting_average: float = 0.0
    #: CURVE to the replay: this learner's certificate (NAME.key_secret, chmod 600; its NAME.key must be among
    #: replay.curve_clients); "" = plaintext (both this and curve_server_key empty)
    curve_certificate: str = ""
    curve_server_key: str = ""  #: CURVE: the replay's public key file (its NAME.key, not .key_secret); "" = plaintext
    zmq_io_threads: int = 1  #: ZeroMQ I/O threads of the sample client, >= 1 (CURVE decrypts in them)

    def __post_init__(self) -> None:
        zmq_endpoint(self, "replay_endpoint", allow_empty=True)
        at_least(self, 1, "batch_size", "prefetch", "torch_threads", "publish_every", "checkpoint_every",
                 "checkpoint_keep", "log_every", "zmq_io_threads")
        at_least(self, 0, "max_updates")
        if not _DEVICE.fullmatch(str(self.device)):
            raise ValueError(f"device must be auto, cpu, mps, cuda or cuda:N (got {self.device!r})")
        above(self, 0, "sample_timeout_s")
        at_least(self, 0, "checkpoint_every_s")
        within(self, 0, 1, "acting_average", open_high=True)
        check_pair(self, "curve_certificate", "curve_server_key", "file")
