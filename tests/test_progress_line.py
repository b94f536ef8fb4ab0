"""The launcher's console progress line says what a person needs, in words and rounded numbers."""

from deploy.progress import duration, progress_line


def test_before_training_the_line_says_what_the_learner_waits_for():
    line = progress_line({"updates": 0, "replay_size": 145, "env_steps": 140, "episodes": 30}, 75, 200)
    assert line.startswith("1m15s | learner waits: replay 145/200 transitions before training starts")
    assert "eval: none yet" in line


def test_while_training_rates_are_rounded_and_success_has_its_episode_count():
    summary = {"updates": 412, "updates_per_s": 0.7134567, "env_steps": 3120.0, "episodes": 1050.0,
               "replay_size": 3300, "samples_per_insert": 1.173456, "weights_version": 42.0,
               "eval_success": 0.85, "eval_episodes": 20.0, "eval_version": 40.0}
    assert progress_line(summary, 725, 200) == (
        "12m05s | updates 412 (0.71/s) | env steps 3,120 (1,050 episodes) | replay 3,300, 1.17 samples per insert"
        " | weights v42 | eval 85% success of 20 episodes (weights v40)")


def test_durations_read_like_a_clock():
    assert [duration(s) for s in (5, 65, 3725)] == ["5s", "1m05s", "1h02m"]
