"""The registry of action families: name -> `(rng, budget) -> Action`, in a fixed order.

The order is part of the dataset: `family_plan` shuffles this list with the seed and dataset.json records
it, so a family is only ever appended, never reordered (the first 21 are the original families; each later
module's FAMILIES is appended as a block). Read-only, so no caller can change which families a build sees.

LAST_ONLY: the families that end off their feet (seated, kneeling, lying): nothing starts from there, so they
only ever end a clip or a sequence.
"""
from __future__ import annotations

from types import MappingProxyType

from . import acrobatics, combat, exercise, falls, gestures, mimed, styles, transitions
from .action import Family
from .in_place import (bow, clap, kick_left, kick_right, punch, raise_both_arms, sit_down, squat, stand_idle,
                       wave_left_hand, wave_right_hand)
from .locomotion import (jump_forward, jump_in_place, run, sidestep_left, sidestep_right, turn_left, turn_right,
                         walk_backward, walk_circle, walk_forward)

GROUPS = (styles, transitions, falls, mimed, gestures, combat, exercise, acrobatics)

FAMILIES: MappingProxyType[str, Family] = MappingProxyType({f.__name__: f for f in (
    walk_forward, walk_backward, walk_circle, run, jump_in_place, jump_forward, wave_right_hand,
    wave_left_hand, kick_right, kick_left, squat, turn_left, turn_right, sit_down, punch, clap,
    sidestep_left, sidestep_right, raise_both_arms, stand_idle, bow,
    *(f for g in GROUPS for f in g.FAMILIES))})

LAST_ONLY: frozenset[str] = frozenset({"sit_down"}.union(*(g.LAST_ONLY for g in GROUPS)))
