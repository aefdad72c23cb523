"""A prompt that names several actions, split into the actions it names, in order: `plan_actions`.

    plan_actions("a person walks forward and then jumps")
        -> [PlannedAction("a person walks forward", None), PlannedAction("a person jumps", None)]
    plan_actions("someone waves for 3 seconds, then sits down")
        -> [PlannedAction("someone waves", 3.0), PlannedAction("someone sits down", None)]

On a bundle trained for endless streams the runtime plays them one after another (endless.StreamContext): each
action until the model ends it (END), or for its stated duration ("for 3 seconds"), then the next. The model was
trained on captions of one to eight actions, but conditioned on a whole "A and then B" caption it plays mostly one
of them (README, "Several actions in one prompt"); one action per conditioning plays both.

The rules are few so that every runtime splits the same way (js/src/plan.js mirrors this file; both are held to
tests/golden/plans.json): a prompt is cut at the sequence words of SEQUENCE_WORDS and at sentence ends; commas
cut too, but only in a prompt that has a sequence word ("walks left, waves, and then sits down"), so "waves,
slowly" stays one action. The first action's subject ("a person", "the man") is given to the later ones that
have none, or have a pronoun ("then he jumps").
"""
from __future__ import annotations

import re
import string
from dataclasses import dataclass

MAX_ACTIONS = 8                # as many actions as the training captions name at most
MOST_SECONDS = 600.0           # a stated duration, at most (an endless stream's fixed length is at most this too)
SEQUENCE_WORDS = ("and then", "and after that", "and afterwards", "and afterward", "after that", "afterwards",
                  "afterward", "then", "followed by", "and finally", "finally", "and next")
SUBJECTS = ("a person", "the person", "this person", "a man", "the man", "a woman", "the woman", "a human",
            "someone", "a character", "the character", "a guy", "the guy", "a girl", "a boy")
PRONOUNS = ("he", "she", "they", "it")
NUMBER_WORDS = {"a": 1, "an": 1, "one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7,
                "eight": 8, "nine": 9, "ten": 10, "fifteen": 15, "twenty": 20, "thirty": 30, "half a": 0.5}
UNITS = {"seconds": 1, "second": 1, "secs": 1, "sec": 1, "s": 1, "minutes": 60, "minute": 60, "min": 60}

# Lower case for matching: ASCII letters only, so a match's indices are the same in the text as typed (str.lower
# changes some texts' length: 'İ' -> 'i̇'), in every runtime.
_LOWER = str.maketrans(string.ascii_uppercase, string.ascii_lowercase)
_WORD = r"(?<![a-z]){}(?![a-z])"
_SEQUENCE = re.compile("|".join(_WORD.format(re.escape(w)) for w in SEQUENCE_WORDS), re.I)
_CUT = re.compile(r"\s*,?\s*(?:" + _SEQUENCE.pattern + r")\s*,?\s*|\s*(?:[;!?]|\.(?!\d))+\s*|\s*(?:->|=>)\s*", re.I)
_DURATION = re.compile(r"\s*,?\s*\bfor\s+(\d+(?:\.\d+)?|" + "|".join(sorted(NUMBER_WORDS, key=len, reverse=True))
                       + r")\s*(" + "|".join(sorted(UNITS, key=len, reverse=True)) + r")\b")
_SUBJECT = re.compile(r"^(?:" + "|".join(re.escape(s) for s in SUBJECTS + PRONOUNS) + r")(?![a-z])")


@dataclass(frozen=True)
class PlannedAction:
    """One action of a prompt: its text (with the prompt's subject) and the seconds it lasts (None: until the model
    ends it)."""
    text: str
    seconds: float | None = None


def plan_actions(text: str) -> list[PlannedAction]:
    """The actions `text` names, in order (one, for a prompt of one action: its text as given, stripped). ValueError
    for more than MAX_ACTIONS actions or a stated duration outside (0, MOST_SECONDS]."""
    low = text.translate(_LOWER)
    if not _SEQUENCE.search(low) and not re.search(r"(?:[;!?]|\.(?!\d))\s*\S|->|=>|\bfor\s", low):
        return [PlannedAction(text)]              # one action, as typed: the common case, untouched
    pieces = _CUT.split(text.strip())
    if _SEQUENCE.search(low):
        pieces = [p for piece in pieces for p in piece.split(",")]
    parts = [re.sub(r"\s+", " ", p).strip(" ,") for p in pieces]
    parts = [p for p in parts if p]
    if len(parts) > MAX_ACTIONS:
        raise ValueError(f"a prompt names at most {MAX_ACTIONS} actions, this one {len(parts)}: give the rest with "
                         f"set_prompt, or as a timeline [(prompt, start_seconds), ...]")
    subject = _subject(parts[0]) if parts else None
    out = []
    for p in parts:
        p, seconds = _duration(p)
        own = _subject(p)
        rest = re.sub(r"^first\s+", "", p[len(own):].lstrip() if own else p, flags=re.I)   # "a person first ..."
        who = subject if subject and (own is None or own.translate(_LOWER) in PRONOUNS) else own
        if rest:
            out.append(PlannedAction(f"{who} {rest}" if who else rest, seconds))
    return out or [PlannedAction(text)]


def _subject(part: str) -> str | None:
    m = _SUBJECT.match(part.translate(_LOWER))
    return part[:m.end()] if m else None


def _duration(part: str) -> tuple[str, float | None]:
    """A part without its "for N seconds", and N (None without one)."""
    m = _DURATION.search(part.translate(_LOWER))
    if m is None:
        return part, None
    amount, unit = m.group(1), m.group(2)
    seconds = (NUMBER_WORDS[amount] if amount in NUMBER_WORDS else float(amount)) * UNITS[unit]
    if not 0 < seconds <= MOST_SECONDS:
        raise ValueError(f"an action's duration must be more than 0 and at most {MOST_SECONDS:g} seconds, got "
                         f"{part[m.start():m.end()].strip()!r}")
    return (part[:m.start()] + part[m.end():]).strip(" ,"), float(seconds)
