"""Control agent pieces: IK hits the pose, OMPL finds a way round an obstacle, Ruckig keeps the Panda's limits."""

import numpy as np

from actors.control.collision import CollisionWorld
from actors.control.ik import IKSolver, quaternion_angle
from actors.control.limits import MAX_VELOCITY
from actors.control.planner import MotionPlanner, cpu_budget, planner_class, segment_is_free
from actors.control.trajectory import parameterise
from actors.sim import shapes
from actors.sim.scene import HOME
from actors.sim.tasks.base import top_down


def test_ik_reaches_the_grasp_pose():
    world = CollisionWorld()
    ik = IKSolver(world)
    for pos in [(0.5, 0.2, 0.1), (0.4, -0.25, 0.3), (0.6, 0.0, 0.02)]:
        quat = top_down(0.3)
        q = ik.solve(pos, quat, HOME)
        assert q is not None
        got_pos, got_orn = world.fk(q)
        assert np.linalg.norm(got_pos - pos) < 0.002 and quaternion_angle(got_orn, quat) < 0.02
    assert ik.solve((1.5, 0.0, 0.2), top_down(0.0), HOME, restarts=2) is None
    world.close()


def test_planner_goes_round_a_wall():
    world = CollisionWorld()
    wall = shapes.box(world.client, (0.1, 0.02, 0.2), (0.5, 0.0, 0.2))
    world.set_obstacles([wall], [])
    ik = IKSolver(world)
    a = ik.solve((0.5, 0.25, 0.15), top_down(0.0), HOME, accept=world.is_valid)
    b = ik.solve((0.5, -0.25, 0.15), top_down(0.0), a, accept=world.is_valid)
    assert not segment_is_free(world, a, b)
    plan = MotionPlanner(world, "RRTConnect", planning_time=5.0).plan(a, b)
    assert plan is not None and plan.used_ompl
    for x, y in zip(plan.path[:-1], plan.path[1:]):
        assert segment_is_free(world, x, y, resolution=0.01)
    world.close()


def test_the_planning_budget_is_cpu_time_so_a_starved_actor_keeps_its_whole_budget():
    """Waiting for a core (here: sleeping) spends no budget; planning work does."""
    import time
    budget = cpu_budget(0.05)
    time.sleep(0.2)  # four budgets of wall-clock time with no CPU spent
    assert not budget()
    spins = 0
    while not budget():  # busy work ends it
        spins += 1
    assert spins > 0


def test_sbl_falls_back_to_lbkpiece():
    from ompl import geometric as og
    assert planner_class("SBL") is getattr(og, "SBL", og.LBKPIECE1)


def test_ruckig_trajectory_respects_velocity_limits_and_ends_at_goal():
    path = np.array([HOME, np.array(HOME) + 0.6, np.array(HOME) + [0.9, 0.2, 0, 0.4, 0, 0.3, -0.5]])
    for pts in (path[:2], path):
        traj = parameterise(pts, velocity_scale=0.5)
        ts = np.linspace(0, traj.duration, 400)
        vel = np.array([traj.sample(t)[1] for t in ts])
        assert np.all(np.abs(vel) <= MAX_VELOCITY * 0.5 + 1e-6)
        assert np.allclose(traj.sample(traj.duration)[0], pts[-1], atol=1e-6)
        assert np.allclose(traj.sample(0.0)[0], pts[0], atol=1e-6)


def test_a_straight_segment_is_executed_on_the_line_the_planner_checked():
    a, b = np.array(HOME), np.array(HOME) + [0.9, -0.3, 0.1, 0.5, 0.0, 0.2, -0.6]
    traj = parameterise(np.stack([a, b]), velocity_scale=0.5)
    for t in np.linspace(0, traj.duration, 50):
        q = traj.sample(t)[0]
        s = np.dot(q - a, b - a) / np.dot(b - a, b - a)
        np.testing.assert_allclose(q, a + s * (b - a), atol=1e-9)  # on the line, not bowed off it


def test_an_open_hand_reaching_straight_down_onto_a_block_does_not_sweep_it_away():
    """Grasping straight from home, with no pre-grasp pose: the planner sees the open fingers and the
    arm follows the checked path. These seeds knocked the block 3-9 cm before either fix."""
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    env = PandaEnv(SimConfig(task="pick_and_lift", cameras=()))
    for seed in (1_000_000, 1_000_002, 1_000_004):
        env.reset(seed)
        block = env.task.pose_of("block0")[0]
        grasp = env.demo_waypoints()[1].action()
        assert not env.step(grasp).unreachable
        assert env.scene.is_grasped(env.task.bodies["block0"])
        assert np.linalg.norm(env.task.pose_of("block0")[0][:2] - block[:2]) < 0.01
    env.close()


def test_agent_reports_per_stage_timings():
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    env = PandaEnv(SimConfig(task="reach_target", cameras=()))
    env.reset(1)
    r = env.step(env.demo_waypoints()[0].action())
    env.close()
    assert set(r.info["timings"]) == {"ik", "plan", "trajectory", "execute", "gripper"}
    assert r.info["control_steps"] >= 1


def test_reachability_test_agrees_with_execution_and_costs_no_second_ik():
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    env = PandaEnv(SimConfig(task="pick_and_lift", cameras=()))
    env.reset(3)
    grasp = env.demo_waypoints()[0].action()
    upside_down = np.concatenate([grasp[:3], [0.0, 0.0, 0.0, 1.0], grasp[7:]])  # fingers up, at the block
    assert not env.reachable(upside_down)
    assert env.reachable(grasp)
    solved = env.control._reached[1]
    r = env.step(grasp)
    assert not r.unreachable and r.info["timings"]["ik"] < 1e-3  # the goal reachable() found was reused
    np.testing.assert_allclose(env.scene.joint_state()[0], solved, atol=0.02)
    assert env.step(upside_down).info["reason"] == "ik_failed"
    env.close()
