"""A real arm as one more actor: a small robot interface, a Franka on franky, cameras, safety.

- ``interface``: what the robot actor needs from any arm (connect, observe, move_to, recover,
  stop, resume, disconnect) and what a move can come to (reached / refused / failed, with why).
- ``safety``: the workspace box, table height and step limit that refuse a pose before the arm
  ever sees it.
- ``franka``: the Franka Panda / FR3 through franky (libfranka).
- ``cameras``, ``realsense``, ``mujoco_camera``: RGB-D cameras that report the same
  ``CameraFrame`` as the simulator (RealSense on a real rig, a MuJoCo render of franky-sim's
  scene in tests).
- ``franky_sim``: franky-sim (the libfranka network protocol over MuJoCo) on loopback with a
  table, a reach target and a camera: the arm the tests and the benchmarks drive.

Nothing here imports franky, pyrealsense2 or MuJoCo at module level outside the modules that
need them: they are the optional ``robot`` extra.
"""
