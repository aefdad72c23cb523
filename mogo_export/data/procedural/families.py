"""The registry of action families: name -> `(rng, budget) -> Action`, in a fixed order.

The order is part of the dataset: `family_plan` shuffles this list with the seed and dataset.json records
it, so a family is only ever appended, never reordered. Read-only, so no caller can change which families
a build sees.
"""
from __future__ import annotations

from types import MappingProxyType

from .action import Family
from .in_place import (bow, clap, kick_left, kick_right, punch, raise_both_arms, sit_down, squat, stand_idle,
                       wave_left_hand, wave_right_hand)
from .locomotion import (jump_forward, jump_in_place, run, sidestep_left, sidestep_right, turn_left, turn_right,
                         walk_backward, walk_circle, walk_forward)

FAMILIES: MappingProxyType[str, Family] = MappingProxyType({f.__name__: f for f in (
    walk_forward, walk_backward, walk_circle, run, jump_in_place, jump_forward, wave_right_hand,
    wave_left_hand, kick_right, kick_left, squat, turn_left, turn_right, sit_down, punch, clap,
    sidestep_left, sidestep_right, raise_both_arms, stand_idle, bow)})
