"""The task ladder: registry, seeded determinism, scripted demos that succeed, unreachable poses that end cleanly."""

import numpy as np
import pytest

from actors.panda_env import PandaEnv
from actors.sim import TASKS, SimConfig, UnknownTaskError, make_task


def test_unknown_task_lists_the_known_ones():
    with pytest.raises(UnknownTaskError) as e:
        make_task("fold_laundry")
    assert isinstance(e.value, ValueError)
    for name in TASKS:
        assert name in str(e.value)


def test_the_ladder_has_eight_tasks_easiest_first():
    assert TASKS == ("reach_target", "push_button", "pick_and_lift", "lift_lid", "open_drawer", "put_in_bin",
                     "stack_wine", "put_item_in_drawer")


@pytest.mark.parametrize("task", TASKS)
def test_scripted_demo_succeeds_and_ends_with_reward_100(task):
    env = PandaEnv(SimConfig(task=task, cameras=()))
    lo, hi = np.array(env.scene_bounds[:3]), np.array(env.scene_bounds[3:])
    for seed in (11, 12):
        obs = env.reset(seed)
        assert obs.step == 0
        waypoints = env.demo_waypoints()
        assert len(waypoints) <= env.episode_length
        for i, wp in enumerate(waypoints):
            assert np.all(lo + 0.05 < wp.position) and np.all(np.array(wp.position) < hi - 0.05)
            r = env.step(wp.action(), linear=wp.linear)
            assert not r.unreachable, r.info
            assert r.observation.step == i + 1
        assert r.success and r.terminal and r.reward == 100.0
    env.close()


def test_same_seed_same_episode():
    env = PandaEnv(SimConfig(task="pick_and_lift", cameras=("front",), image_size=32))
    a = env.reset(5)
    ra = env.step(env.demo_waypoints()[0].action())
    b = env.reset(5)
    rb = env.step(env.demo_waypoints()[0].action())
    env.close()
    assert np.array_equal(a.cameras["front"].rgb, b.cameras["front"].rgb)
    assert np.array_equal(ra.observation.joint_positions, rb.observation.joint_positions)


@pytest.mark.parametrize("reward", [0.0, -1.0])
def test_unreachable_pose_ends_the_episode_without_raising(reward):
    env = PandaEnv(SimConfig(task="reach_target", cameras=(), unreachable_reward=reward))
    env.reset(0)
    far = np.array([3.0, 0.0, 0.3, 1, 0, 0, 0, 1.0])
    r = env.step(far)
    assert r.unreachable and r.terminal and not r.success and r.reward == reward
    assert r.info["reason"] == "out_of_workspace"
    env.reset(0)
    r = env.step(np.array([0.8, 0.45, 0.9, 1, 0, 0, 0, 1.0]))  # inside the cube, beyond the arm's reach
    assert r.unreachable and r.info["reason"] == "ik_failed"
    r = env.step(np.full(8, np.nan))
    assert r.unreachable and r.info["reason"] == "invalid_action"
    env.close()


def test_observation_carries_the_proprioception():
    env = PandaEnv(SimConfig(task="push_button", cameras=()))
    obs = env.reset(0)
    env.close()
    assert obs.gripper_pose.shape == (7,) and abs(np.linalg.norm(obs.gripper_pose[3:]) - 1) < 1e-5
    assert obs.gripper_open == 1.0
    assert obs.finger_positions.shape == (2,) and np.all((0 <= obs.finger_positions) & (obs.finger_positions <= 0.04))
    assert obs.joint_positions.shape == obs.joint_velocities.shape == (7,)


@pytest.mark.parametrize("task", ["reach_target", "pick_and_lift"])
def test_the_target_is_red_in_every_episode_as_in_rlbench_variation_0(task):
    """C2F-ARM learns variation 0: the target's colour is what tells it from the distractors."""
    from actors.sim import shapes
    from actors.sim.tasks import make_task

    t = make_task(task)
    for seed in range(20):
        t.sample(np.random.default_rng(seed))
        colours = [shapes.COLOURS[c] if isinstance(c, str) else c for c in t.colours]
        assert colours[0] == shapes.COLOURS["red"] and shapes.COLOURS["red"] not in colours[1:]
        assert len(set(colours)) == 3


@pytest.mark.parametrize("task", ["push_button", "lift_lid", "open_drawer", "put_in_bin", "stack_wine",
                                  "put_item_in_drawer"])
def test_tasks_of_one_rlbench_variation_look_the_same_in_every_episode(task):
    """Only place and yaw change between episodes, as in the one variation C2F-ARM trains on."""
    from actors.sim.bullet import p

    env = PandaEnv(SimConfig(task=task, cameras=()))
    looks = set()
    for seed in range(6):
        env.reset(seed)
        looks.add(tuple((name, tuple(tuple(v[7]) for v in p.getVisualShapeData(body, physicsClientId=env.scene.client)))
                        for name, body in sorted(env.task.bodies.items())))
    env.close()
    assert len(looks) == 1


def test_stack_wine_is_one_layout_the_bottle_left_of_the_rack_as_rlbench():
    """Mirroring the pair at random (revisions 1-2) doubled the modes 10 demos must cover."""
    from actors.sim.tasks.stack_wine import StackWine

    t = StackWine.__new__(StackWine)
    for seed in range(50):
        t.sample(np.random.default_rng(seed))
        assert t.bottle[1] >= 0.15 and t.rack[1] <= -0.05
        assert -np.pi / 2 - np.pi / 8 <= t.rack_yaw <= -np.pi / 2 + np.pi / 8


def test_put_item_in_drawer_is_one_layout_the_chest_left_and_the_block_right():
    """As stack_wine: 10 demos cover one layout better than two mirrored ones."""
    from actors.sim.tasks.put_item_in_drawer import PutItemInDrawer

    t = PutItemInDrawer.__new__(PutItemInDrawer)
    for seed in range(50):
        t.sample(np.random.default_rng(seed))
        assert t.position[1] >= 0.08 and t.block[1] <= -0.22


def test_demos_cached_for_an_older_scene_of_a_task_are_not_reused():
    from deploy.config import load_config
    from deploy.roles import demo_dir

    def directory(task):
        return demo_dir(load_config(preset="cpu-small", overrides=({"sim": {"task": task}},))).name

    assert directory("pick_and_lift") == "pick_and_lift-r2-front-128px"  # revision 2: the target is always red
    assert directory("push_button") == "push_button-r2-front-128px"  # revision 2: one colour
    assert directory("reach_target") == "reach_target-front-128px"
