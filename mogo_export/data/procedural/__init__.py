"""A procedural text-to-motion dataset in the HumanML3D layout: keyframed actions, their captions, and the
writer. `build_dataset` (the entry point) and `main` (the command line) are exported from here.

Pipeline per clip, one module per step:
  families.py (locomotion.py, in_place.py) sample an action's parameters and build its joint-angle tracks
      (pose.Pose, animated with curves.py and gaits.py) and verb phrases, within an action.TimeBudget
  clips.py      picks the families of each clip, cross-fades two-action sequences, and samples captions
      (captions.py); sequences.py strings 3-8 actions into 20-60 s with one timed caption per action
  kinematics.py forward kinematics on the HUMANML3D skeleton (root at the origin)
  grounding.py  places the root so heels and toes that land on the floor stay where they landed, and the
      lowest one is on y=0, then takes up what the pose leaves over with leg IK -> joints (T, 22, 3)
  writer.py     `extract_features` (T-1, 263) and every file of the HumanML3D folder layout, and each long
      sequence's segments in dataset.json; see `build_dataset`. Same seed -> byte-identical files.
No module holds mutable state: what varies between calls (the generator, the time budget) is passed in.
"""
from .writer import build_dataset, main

__all__ = ["build_dataset", "main"]
