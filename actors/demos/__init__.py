"""Scripted demonstrations: generation, MCAP files, keyframe discovery and demo augmentation."""

from actors.demos.augmentation import DemoEpisode, demo_to_transitions
from actors.demos.keyframes import discover_keyframes
from protocol.episode_file import Demo, DemoFileError, load_demo, write_demo

__all__ = ["Demo", "DemoEpisode", "DemoFileError", "demo_to_transitions", "discover_keyframes", "load_demo",
           "write_demo"]
