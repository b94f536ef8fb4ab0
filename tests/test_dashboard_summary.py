"""The dashboard's training summary: what a person watches while C2F-ARM learns."""

from dashboard.registry import RoleTable
from protocol.messages import Status


def _status(role: str, instance: str, **counters) -> Status:
    return Status(role=role, instance=instance, run_id="r", pid=1, host="h", time=0.0, counters=counters)


def test_summary_adds_up_actors_and_robots_and_shows_each_ones_policy_lag():
    table = RoleTable("r")
    for role, instance, counters in (
        ("learner", "learner", {"updates": 120, "updates_per_s": 0.5, "weights_version": 12}),
        ("replay", "replay", {"size_transitions": 900, "samples_per_insert": 1.5}),
        ("actor", "actor-0", {"env_steps": 300, "episodes": 100, "weights_version": 12}),
        ("actor", "actor-1", {"env_steps": 200, "episodes": 70, "weights_version": 9}),
        ("robot", "robot-0", {"env_steps": 40, "episodes": 10, "weights_version": 11}),
        ("eval", "eval", {"eval_success": 0.8, "eval_version": 10}),
    ):
        table.on_token(role, instance, True)
        table.on_status(_status(role, instance, **counters))

    summary = table.snapshot()["summary"]

    assert summary["updates"] == 120 and summary["weights_version"] == 12
    assert summary["env_steps"] == 540 and summary["episodes"] == 180
    assert summary["replay_size"] == 900
    assert summary["policy_lag"] == {"actor-0": 0, "actor-1": 3, "robot-0": 1}
    assert summary["eval_success"] == 0.8 and summary["eval_version"] == 10


def test_a_gone_actor_no_longer_counts():
    table = RoleTable("r")
    table.on_token("actor", "actor-0", True)
    table.on_status(_status("actor", "actor-0", env_steps=50, weights_version=1))
    table.on_token("actor", "actor-0", False)
    summary = table.snapshot()["summary"]
    assert summary["env_steps"] == 0 and summary["policy_lag"] == {} and summary["updates"] is None


def test_in_a_run_without_an_evaluator_the_robots_own_greedy_evaluation_is_shown():
    from deploy.progress import progress_line

    table = RoleTable("r")
    for role, instance, counters in (
        ("learner", "learner", {"updates": 60, "weights_version": 6}),
        ("robot", "robot-0", {"env_steps": 40, "episodes": 10, "weights_version": 6,
                              "eval_success": 0.9, "eval_episodes": 20, "eval_version": 5}),
    ):
        table.on_token(role, instance, True)
        table.on_status(_status(role, instance, **counters))

    summary = table.snapshot()["summary"]

    assert summary["eval_success"] == 0.9 and summary["eval_version"] == 5
    assert "eval 90% success of 20 episodes (weights v5)" in progress_line(summary, 300.0, 200)
