"""Exercise and play: jumping jacks, lunges, arm circles, swimming strokes standing, dance steps.

Each is a family as action.py describes, `(rng, budget) -> Action`. FAMILIES lists this module's families in
their fixed order (families.py appends it to the registry); WORDS holds every caption word they use that the
shared lexicon (captions.py) lacks; LAST_ONLY names the families that do not end standing.
"""
from __future__ import annotations

FAMILIES: tuple = ()
WORDS: dict = {}
LAST_ONLY: tuple[str, ...] = ()
