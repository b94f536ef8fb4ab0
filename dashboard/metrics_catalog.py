"""What every role status counter means on ``/metrics``: one :class:`Family` per exported name.

Roles report a flat ``name -> float`` map (``protocol.Status.counters``) for the page; Prometheus
needs more: a type, a HELP line, base units, and one name for one meaning. This catalogue adds
that, by (role, counter name), without importing the roles (the dashboard stays light):

- a monotonic count is a ``counter`` named ``..._total``; everything else is a ``gauge``;
- units are base units (``_seconds``, ``_bytes``): ``checkpoint_max_pause_ms`` is scaled by 1e-3;
- a word that means different things in two roles gets a role prefix
  (``c2farm_replay_duplicate_episodes_total`` vs ``c2farm_outbox_duplicate_acks_total``); what
  several roles share keeps one name, with ``role`` and ``instance`` as labels: the outbox
  (actors, robot actors, the demo source), the weights follower (those actors and the evaluator),
  the acting counts (``c2farm_actor_episodes_total{role="actor"|"robot"}``);
- ``<prefix><reason>`` counters become one family with a label (``ingest_rejected_decode`` ->
  ``c2farm_replay_ingest_rejected_total{reason="decode"}``);
- :class:`Skip` marks what is deliberately not exported: rates (``*_per_s``) and ratios that
  PromQL computes from the counters (``rate()``, a division), and aggregates that are exactly the
  sum of a by-reason family whose reasons are all present from the start (``sum without
  (reason)``). An aggregate whose breakdown starts empty (errors by exception type) *is*
  exported, under its own name, so an alert has a zero series to watch.

A counter missing here is still exported, as ``c2farm_undocumented{name=...}`` (see
``dashboard/metrics.py``); ``tests/test_metrics.py`` fails when code reports one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Union


@dataclass(frozen=True)
class Family:
    """One exported metric family."""

    name: str  #: full exported name (counters end in ``_total``)
    kind: Literal["counter", "gauge"]
    help: str
    scale: float = 1.0  #: multiplies the reported value into the base unit
    label: str = ""  #: for a by-reason family: the label that carries what follows the prefix


@dataclass(frozen=True)
class Skip:
    """A counter the page shows but /metrics leaves out, and why."""

    why: str


Entry = Union[Family, Skip]


def _c(name: str, help: str, label: str = "") -> Family:
    return Family(f"c2farm_{name}_total", "counter", help, label=label)


def _g(name: str, help: str, scale: float = 1.0, label: str = "") -> Family:
    return Family(f"c2farm_{name}", "gauge", help, scale, label)


RATE = Skip("a rate: PromQL's rate() over the matching counter")
RATIO = Skip("a ratio of exported counters: divide them in PromQL")

# -- parts several roles share (same meaning, so one name) ---------------------------------
_OUTBOX: dict[str, Entry] = {  # protocol/episode_outbox.py: actors and the demo source
    "sent": _c("outbox_sent", "Episodes published for the first time (resends are not counted here)."),
    "acked": _c("outbox_acked", "Episodes the replay acknowledged as stored."),
    "duplicates": _c("outbox_duplicate_acks", "Episodes the replay acknowledged as duplicates of stored ones."),
    "rejected": _c("outbox_rejected_acks", "Episodes the replay acknowledged as rejected (not stored, not resent)."),
    "resent": _c("outbox_resent", "Episode resends after no acknowledgement within resend_after_s."),
    "dropped": _c("outbox_dropped", "Episodes dropped unacknowledged because the outbox stayed full."),
    "bad_acks": _c("outbox_bad_acks", "Acknowledgements that could not be decoded."),
    "forged_acks": _c("outbox_forged_acks", "Acknowledgements naming a pending episode but another payload digest."),
    "unmatched_acks": _c("outbox_unmatched_acks",
                         "Acknowledgements for no pending episode (e.g. the second of a resend)."),
    "outbox_pending": _g("outbox_pending_episodes", "Episodes published and not yet acknowledged."),
}
_FOLLOWER: dict[str, Entry] = {  # protocol/weights_follower.py: actors and the evaluator
    "weights_announced": _g("weights_announced_version",
                            "Weights version the learner's heartbeat last announced (-1: none heard yet)."),
    "weights_superseded": _c("weights_superseded", "Weights payloads pushed out of the inbox unread by newer ones."),
    "weights_bad_announcements": _c("weights_bad_announcements", "Learner status messages that could not be read."),
}
_FOLLOWER_BY = {"weights_rejected_": _c("weights_rejected", "Weights updates not taken, by reason.", "reason")}

_ACTING: dict[str, Entry] = {  # what every acting process counts: the simulated actor and the robot actor
    **_OUTBOX,
    **_FOLLOWER,
    "episodes": _c("actor_episodes", "Episodes this actor collected."),
    "env_steps": _c("actor_env_steps", "Environment steps (decisions) this actor took."),
    "successes": _c("actor_successes", "Episodes this actor ended in success."),
    "timeouts": _c("actor_timeout_episodes", "Episodes that ran out of decisions."),
    "unreachable": _c("actor_unreachable_episodes",
                      "Episodes ended on a pose the arm could not reach, whatever the reason (or none given)."),
    "reach_checks": _c("actor_reach_checks", "Reachability tests run while choosing poses."),
    "reach_replaced": _c("actor_reach_replaced",
                         "Decisions whose first choice was unreachable and a reachable candidate replaced it."),
    "repeats_skipped": _c("actor_repeats_skipped",
                          "Decisions that repeated the gripper's pose, replaced by the best one that moves."),
    "weights_version": _g("actor_weights_version", "Weights version this actor acts with (0: initial network)."),
    "epsilon": _g("actor_epsilon", "Exploration probability this actor acts with now (actor.epsilon, decayed)."),
    "success_rate": RATIO,
    "unreachable_rate": RATIO,
}
_EVALUATION: dict[str, Entry] = {  # the latest greedy evaluation: the evaluator's, or a robot's own
    "eval_success": _g("eval_success_ratio", "Greedy success rate of the latest evaluation (0 to 1)."),
    "eval_episodes": _g("eval_episodes", "Episodes in the latest evaluation."),
    "eval_return": _g("eval_mean_return", "Mean episode return of the latest evaluation."),
    "eval_unreachable": _g(
        "eval_unreachable_ratio", "Share of the latest evaluation's episodes that ended unreachable (0 to 1)."
    ),
    "eval_version": _g("eval_weights_version", "Weights version of the latest evaluation."),
    "eval_env_steps": _g(
        "eval_env_steps", "Env steps the run had collected when the evaluated weights were published."
    ),
}
_UNREACHABLE_BY = ("unreachable_", _c("actor_unreachable_episodes_by_reason",
                                      "Episodes ended unreachable, by the control agent's reason.", "reason"))

#: role -> counter name -> entry (exact names; checked before the prefixes of BY_LABEL)
EXACT: dict[str, dict[str, Entry]] = {
    "actor": {
        **_ACTING,
        "weights_latency_s": _g("actor_weights_latency_seconds",
                                "Publish-to-receipt delay of the newest weights update (wall clocks)."),
    },
    "robot": {  # actors/robot: the actor loop on a real arm (or franky-sim), a person giving reward
        **_ACTING,
        **_EVALUATION,  # robot.evaluate: the arm plays the greedy episodes itself
        "operator_stops": _c("robot_operator_stopped_episodes", "Episodes cut short by an operator stop (dropped)."),
        "operator_rejected": _c("robot_operator_messages_rejected",
                                "Operator messages refused: undecodable, or addressed to another actor."),
        "moves": _c("robot_arm_moves", "Moves sent to the arm."),
        "reached": _c("robot_arm_moves_reached", "Moves that reached their pose."),
        "failed": _c("robot_arm_moves_failed", "Moves that failed on the arm."),
        "stops": _c("robot_arm_stops", "Stop commands sent to the arm."),
        "recoveries": _c("robot_arm_recoveries", "Error recoveries run on the arm."),
        "reconnects": _c("robot_arm_reconnects", "Connections to the arm reopened by a recovery."),
        "unwinds": _c("robot_arm_unwinds", "Joint-space moves to the home joints after a reset could not reach home."),
        "replans": _c("robot_arm_replans", "Motions the trajectory generator refused, planned again slower."),
        "paused": _g("robot_paused", "1 while an operator stop pauses this robot actor."),
        "stop_to_still_s": _g("robot_stop_to_still_seconds",
                              "From the last stop command until the arm stood still (NaN: no stop yet)."),
    },
    "eval": {
        **_FOLLOWER,
        **_EVALUATION,
        "evaluations": _c("eval_evaluations", "Evaluations completed since the evaluator started."),
    },
    "demos": {
        **_OUTBOX,
        "demos": _c("demos_files_published", "Demo files whose episodes were published."),
        "demo_episodes": _c("demos_episodes_published", "Demo-augmented episodes published (several per demo file)."),
    },
    "learner": {
        "updates": _c("learner_updates", "Training updates done (skipped non-finite updates included)."),
        "samples": _c("learner_samples", "Transitions trained on (batch rows of the updates done)."),
        "weights_version": _g("learner_weights_version", "Newest weights version the learner published."),
        "skipped_updates": _c("learner_skipped_updates", "Updates skipped for a non-finite loss or gradient."),
        "rejected_batches": _c("learner_rejected_batches",
                               "Sampled batches refused as poisoned (non-finite, labels out of range)."),
        "weights_refused": _c("learner_weights_refused",
                              "Weights snapshots not published because they were non-finite."),
        "checkpoints_refused": _c("learner_checkpoints_refused",
                                  "Checkpoints not written because the state was non-finite."),
        "updates_per_s": RATE,
        "samples_per_s": RATE,
    },
    "replay": {
        "size_transitions": _g("replay_stored_transitions", "Transitions stored."),
        "size_episodes": _g("replay_stored_episodes", "Episodes stored."),
        "demo_transitions": _g("replay_stored_demo_transitions", "Stored transitions from demonstrations."),
        "agent_transitions": _g("replay_stored_agent_transitions",
                                "Stored transitions from actors (not demonstrations)."),
        "bytes": _g("replay_stored_bytes", "Bytes of stored episodes."),
        "capacity_transitions": _g("replay_capacity_transitions",
                                   "Transitions the replay holds at most (replay.capacity_transitions)."),
        "capacity_bytes": _g("replay_capacity_bytes", "Bytes the replay holds at most (replay.capacity_bytes)."),
        "transitions_inserted": _c("replay_transitions_inserted", "Transitions inserted (the rate limiter's inserts)."),
        "transitions_sampled": _c("replay_transitions_sampled", "Transitions served in sampled batches."),
        "demo_transitions_sampled": _c("replay_demo_transitions_sampled",
                                       "Demonstration transitions served in sampled batches."),
        "episodes_stored": _c("replay_episodes_stored", "Episodes stored (and acknowledged)."),
        "episodes_evicted": _c("replay_episodes_evicted", "Episodes evicted to make room (FIFO)."),
        "priority_updates": _c("replay_priority_updates", "Priorities updated."),
        "stale_priority_updates": _c("replay_stale_priority_updates",
                                     "Priority updates for rows since overwritten (ignored)."),
        "batches_served": _c("replay_batches_served", "Sample batches served."),
        "sample_timeouts": _c("replay_sample_timeouts",
                              "Sample requests answered 'retry' after waiting too long for a batch."),
        "dropped_replies": _c("replay_dropped_replies", "Sample replies dropped (the ZeroMQ peer was gone or full)."),
        "duplicates": _c("replay_duplicate_episodes",
                         "Episodes received again (a resend) and acknowledged as duplicates."),
        "insert_wait_timeouts": _c("replay_insert_wait_timeouts",
                                   "Inserts that waited insert_wait_timeout_s on the rate limiter, then went ahead."),
        "identity_released": _c("replay_identity_released", "Actor ids freed because their session's token went away."),
        "checkpoints": _c("replay_checkpoints", "Replay checkpoints written."),
        "ingest_queue": _g("replay_ingest_queue_episodes", "Episodes received and waiting for the ingest thread."),
        "ingest_queue_bytes": _g("replay_ingest_queue_bytes", "Bytes waiting for the ingest thread."),
        "ingest_queue_peak": _g("replay_ingest_queue_peak_episodes",
                                "Most episodes ever waiting for the ingest thread."),
        "ingest_queue_peak_bytes": _g("replay_ingest_queue_peak_bytes",
                                      "Most bytes ever waiting for the ingest thread."),
        "ingest_senders": _g("replay_ingest_senders", "Senders with episodes waiting for the ingest thread."),
        "identity_bindings": _g("replay_identity_bindings", "Actor ids bound to a Zenoh session."),
        "dedup_actors": _g("replay_dedup_actors", "Actors whose episode ids are remembered for deduplication."),
        "sample_requests_pending": _g("replay_sample_requests_pending",
                                      "Sample requests waiting for the rate limiter."),
        "samples_per_insert_target": _g("replay_samples_per_insert_target",
                                        "Configured samples per inserted transition (0: only the minimum size gates)."),
        "last_checkpoint_time": _g("replay_last_checkpoint_timestamp_seconds",
                                   "When the last checkpoint finished (Unix time; 0: none yet)."),
        "last_checkpoint_seconds": _g("replay_last_checkpoint_duration_seconds", "How long the last checkpoint took."),
        "last_checkpoint_bytes": _g("replay_last_checkpoint_size_bytes", "Size of the last checkpoint."),
        "checkpoint_max_pause_ms": _g("replay_checkpoint_max_pause_seconds",
                                      "Longest time a checkpoint held ingest and sampling.", scale=1e-3),
        "restore_seconds": _g("replay_restore_duration_seconds", "How long restoring at start took."),
        "wal_replayed_episodes": _g("replay_wal_replayed_episodes",
                                    "Episodes replayed from the write-ahead log at start."),
        "wal_skipped_records": _g("replay_wal_skipped_records",
                                  "Write-ahead-log records skipped at start (unreadable or refused)."),
        "ingest_errors": _c("replay_ingest_errors",
                            "Unexpected errors while ingesting episodes (all exception types)."),
        "callback_errors": _c("replay_callback_errors", "Unexpected errors in Zenoh callbacks (all exception types)."),
        "ack_failures": _c("replay_ack_failures",
                           "Acknowledgements that could not be published (all exception types)."),
        "sample_errors": _c("replay_sample_errors", "Unexpected errors serving samples (all exception types)."),
        "checkpoint_failures": _c("replay_checkpoint_failures", "Checkpoints that failed (all exception types)."),
        "rejected": Skip("sum of c2farm_replay_ingest_rejected_total over reason"),
        "zmq_rejected": Skip("sum of c2farm_replay_zmq_rejected_total over reason"),
        "dropped_backpressure": Skip('equals c2farm_replay_ingest_dropped_total{reason="backpressure"}'),
        "priority_updates_rejected": Skip('sum of c2farm_replay_zmq_rejected_total{reason=~"priorities_.*"}'),
        "inserts_per_s": RATE,
        "samples_per_s": RATE,
        "samples_per_insert": RATIO,
    },
    "dashboard": {
        "rejected_messages": Skip("the dashboard exports the same count as c2farm_rejected_status_messages_total"),
        "http_refused_token": _c("dashboard_http_refused_token",
                                 "HTTP requests the dashboard refused for a missing or wrong token."),
    },
    "router": {},
}


def _by_reason(name: str, help: str) -> Family:
    return _c(name, help, "reason")


def _by_exception(name: str, help: str) -> Family:
    return _c(f"{name}_by_exception", help, "exception")


#: role -> (prefix, family): ``<prefix><value>`` is exported with ``family.label=<value>``
BY_LABEL: dict[str, tuple[tuple[str, Family], ...]] = {
    "actor": (*_FOLLOWER_BY.items(), _UNREACHABLE_BY),
    "robot": (
        *_FOLLOWER_BY.items(),
        _UNREACHABLE_BY,
        ("refused_", _by_reason("robot_poses_refused", "Poses the safety limits refused before the arm saw them.")),
        ("operator_", _c("robot_operator_commands", "Operator commands received, by action.", "action")),
    ),
    "eval": tuple(_FOLLOWER_BY.items()),
    "learner": (
        ("loss/depth", _g("learner_loss", "TD loss of the latest update, by Q-attention depth.", label="depth")),
        ("q_chosen/depth", _g("learner_q_chosen", "Mean Q of the chosen voxel in the latest update, by depth.",
                              label="depth")),
    ),
    "replay": (
        ("ingest_rejected_", _by_reason("replay_ingest_rejected", "Episodes refused at ingest, by reason.")),
        ("ingest_dropped_", _by_reason("replay_ingest_dropped",
                                       "Episodes dropped unacknowledged at ingest (the actor resends), by reason.")),
        ("ingest_suspect_", _by_reason("replay_ingest_suspect",
                                       "Episodes stored but suspect (an id reused with another payload), by reason.")),
        ("zmq_rejected_", _by_reason("replay_zmq_rejected",
                                     "Sample requests and priority updates refused, by reason.")),
        ("ingest_error_", _by_exception("replay_ingest_errors",
                                        "Unexpected errors while ingesting, by exception type.")),
        ("callback_error_", _by_exception("replay_callback_errors",
                                          "Unexpected errors in Zenoh callbacks, by exception type.")),
        ("ack_error_", _by_exception("replay_ack_failures", "Acknowledgements not published, by exception type.")),
        ("zmq_error_", _by_exception("replay_sample_errors", "Unexpected errors serving samples, by exception type.")),
        ("checkpoint_error_", _by_exception("replay_checkpoint_failures", "Failed checkpoints, by exception type.")),
    ),
}


def lookup(role: str, name: str) -> tuple[Entry, str] | None:
    """The entry for ``name`` as ``role`` reports it, with the label value (``""`` for an exact name); None: missing."""
    exact = EXACT.get(role, {}).get(name)
    if exact is not None:
        return exact, ""
    for prefix, family in BY_LABEL.get(role, ()):
        if name.startswith(prefix) and len(name) > len(prefix):
            return family, name[len(prefix):]
    return None


def families() -> dict[str, Family]:
    """Every family the catalogue can export, by name (a name shared by roles maps to one Family)."""
    out: dict[str, Family] = {}
    for role in EXACT:
        entries = [e for e in EXACT[role].values() if isinstance(e, Family)] + [f for _, f in BY_LABEL.get(role, ())]
        for family in entries:
            out.setdefault(family.name, family)
    return out
