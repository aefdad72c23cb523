"""Control: where a character goes. The contract of the step graph's `control` input (vector.py), the requests a game
makes (targets.py) and one stream's state between them (steering.py)."""
from .steering import Steerable, Steering
from .targets import FollowPath, GameRoot, Steer, WalkTo

__all__ = ["FollowPath", "GameRoot", "Steer", "Steerable", "Steering", "WalkTo"]
