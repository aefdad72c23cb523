"""Requests as JSON objects, as a game sends them on a pipe (`mogo stream --follow`) or a socket:

    {"prompt": "a person runs"}                       the action (a plain line of text says the same)
    {"goal": [4.0, 2.0], "speed": 1.3}                walk_to (speed optional)
    {"path": [[0, 0], [2, 1], [5, 1]], "speed": 2.5}  follow_path (speed optional)
    {"velocity": [0.0, 1.4], "facing": [1.0, 0.0]}    steer (facing optional)
    {"root": [x, z, heading]}                         set_root: the game owns the capsule
    {"release": true}                                 back to text only

A prompt may come with one control request in the same object. A bad line changes nothing: `parse_request` checks
the line's form and its prompt, and `Request.apply` makes the control call first, whose own checks run before it
changes anything; one ValueError names what is wrong.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

from ..checks import shown
from ..text import check_texts

CONTROLS = {"goal": {"speed"}, "path": {"speed"}, "velocity": {"facing"}, "root": set(), "release": set()}
KEYS = {"prompt"} | set(CONTROLS) | {k for extra in CONTROLS.values() for k in extra}


@dataclass(frozen=True)
class Request:
    prompt: str | None               # the new action, or None: the action stays
    control: dict | None             # {"goal": ..., "speed": ...} etc., or None: the control stays

    def apply(self, character, **prompt_options) -> None:
        """Control first (its own checks run before it changes anything), then the prompt (already checked)."""
        c = self.control
        if c is not None:
            if "goal" in c:
                character.walk_to(c["goal"], **_given(c, "speed"))
            elif "path" in c:
                character.follow_path(c["path"], **_given(c, "speed"))
            elif "velocity" in c:
                character.steer(c["velocity"], c.get("facing"))
            elif "root" in c:
                root = c["root"]
                if not isinstance(root, list) or len(root) != 3:
                    raise ValueError(f"root must be [x, z, heading], got {shown(root)}")
                character.set_root(*root)
            else:
                character.release()
        if self.prompt is not None:
            character.set_prompt(self.prompt, **prompt_options)


def _given(c: dict, key: str) -> dict:
    return {key: c[key]} if key in c else {}


def parse_request(line: str) -> Request:
    """One line: a JSON object (first character `{`) or a plain prompt."""
    if not line.lstrip().startswith("{"):
        return Request(check_texts([line])[0], None)
    try:
        obj = json.loads(line)
    except (ValueError, RecursionError) as e:      # RecursionError: nesting deeper than the parser goes
        raise ValueError(f"a request line is not JSON: {str(e)[:120]}") from None
    return request_from(obj)


def request_from(obj) -> Request:
    """A request already parsed from JSON (a line of `mogo stream --follow`, a motion server's message)."""
    if not isinstance(obj, dict):
        raise ValueError(f"a request must be a JSON object, got {type(obj).__name__}")
    unknown = sorted(set(obj) - KEYS)
    if unknown:
        raise ValueError(f"a request has unknown field(s) {shown(unknown)}; known: {', '.join(sorted(KEYS))}")
    kinds = [k for k in CONTROLS if k in obj]
    if len(kinds) > 1:
        raise ValueError(f"a request asks for one control at a time, got {', '.join(kinds)}")
    allowed = CONTROLS[kinds[0]] if kinds else set()
    stray = sorted(k for k in obj if k not in CONTROLS and k != "prompt" and k not in allowed)
    if stray:
        raise ValueError(f"field(s) {', '.join(stray)} need "
                         + " or ".join(k for k, extra in CONTROLS.items() if set(stray) <= extra))
    if "release" in obj and obj["release"] is not True:
        raise ValueError(f"release must be true, got {shown(obj['release'])}")
    if "prompt" in obj and not isinstance(obj["prompt"], str):
        raise ValueError(f"prompt must be a string, got {type(obj['prompt']).__name__}")
    if not kinds and "prompt" not in obj:
        raise ValueError("a request needs a prompt or a control (" + ", ".join(CONTROLS) + ")")
    prompt = check_texts([obj["prompt"]])[0] if "prompt" in obj else None
    control = {k: v for k, v in obj.items() if k != "prompt"} or None
    return Request(prompt, control)
