"""Every word of the procedural captions: the phrasing helpers the families build their verb phrases with,
the subjects and sequence templates that turn phrases into captions, and the part-of-speech lexicon that
writes HumanML3D's `word/POS` token field.

Kept together because they must agree: every word a family or template can produce has to be in the
lexicon, and the build fails loudly on one that is not (tests check every family's phrasing against it).
"""
from __future__ import annotations

import functools

import numpy as np

SPEED_WORDS = {"slow": "slowly", "normal": "", "fast": "quickly"}
COUNT_WORDS = {1: "once", 2: "twice", 3: "three times", 4: "four times", 5: "five times", 6: "six times",
               7: "seven times", 8: "eight times", 9: "nine times", 10: "ten times"}
NUMBER_WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven", 8: "eight",
                9: "nine", 10: "ten", 11: "eleven", 12: "twelve", 13: "thirteen", 14: "fourteen", 15: "fifteen",
                16: "sixteen", 17: "seventeen", 18: "eighteen", 19: "nineteen", 20: "twenty"}


def adverb(speed: str) -> str:
    """" slowly" / " quickly" (with the leading space) for a speed, "" for a normal pace."""
    return (" " + SPEED_WORDS[speed]) if SPEED_WORDS[speed] else ""


def how_often(n: int) -> str:
    return COUNT_WORDS[n]


SUBJECTS = (("a person", "their"), ("a man", "his"), ("a woman", "her"), ("someone", "their"),
            ("the person", "their"), ("a human", "their"), ("the man", "his"), ("this person", "their"))
SEQUENCE_TEMPLATES = ("{s} {a} and then {b}", "{s} {a}, then {b}", "{s} first {a} and then {b}",
                      "{s} {a} and after that {b}", "{s} {a}, and afterwards {b}")


def sample_captions(phrase_sets: list[list[str]], rng: np.random.Generator) -> list[str]:
    """3 or 4 differently worded captions: distinct phrasings, each with a sampled subject."""
    n = int(rng.integers(3, 5))
    picks = [rng.permutation(len(p)) for p in phrase_sets]
    out: list[str] = []
    for i in range(n):
        subject, pos = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
        parts = [p[int(k[i % len(k)])].replace("{pos}", pos) for p, k in zip(phrase_sets, picks)]
        if len(parts) == 1:
            text = f"{subject} {parts[0]}"
        else:
            tpl = SEQUENCE_TEMPLATES[int(rng.integers(len(SEQUENCE_TEMPLATES)))]
            text = tpl.format(s=subject, a=parts[0], b=parts[1])
        out.append(text + ".")
    return list(dict.fromkeys(out))  # same subject and phrasing twice: keep one


def single_caption(phrases: list[str], rng: np.random.Generator) -> str:
    """One caption of one action: a sampled subject and phrasing (a long sequence's per-action line)."""
    subject, pos = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
    return f"{subject} {phrases[int(rng.integers(len(phrases)))].replace('{pos}', pos)}."


LONG_TEMPLATES = ("{s} {a}, then {b}, and finally {c}", "{s} first {a}, then {b}, and finally {c}",
                  "{s} {a}, then {b} and then {c}")


def sequence_captions(phrase_sets: list[list[str]], rng: np.random.Generator) -> list[str]:
    """1 or 2 differently worded captions naming every action of a long sequence in order."""
    out = []
    for _ in range(int(rng.integers(1, 3))):
        subject, pos = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
        # the shorter of two phrasings: eight actions in one sentence are long enough
        parts = [min((p[int(k)] for k in rng.choice(len(p), 2, replace=False)), key=len).replace("{pos}", pos)
                 for p in phrase_sets]
        tpl = LONG_TEMPLATES[int(rng.integers(len(LONG_TEMPLATES)))]
        out.append(tpl.format(s=subject, a=parts[0], b=", then ".join(parts[1:-1]), c=parts[-1]) + ".")
    return list(dict.fromkeys(out))


# A small POS lexicon covering every word the captions use, tagged like HumanML3D's texts (spaCy's
# universal tags, only NOUN and VERB lemmatised, punctuation dropped). The build fails loudly on a word
# missing here rather than guessing.
_WORDS = {
    "DET": "a the this both all his her their",
    "PRON": "someone it nothing them that",
    "AUX": "is",
    "CCONJ": "and",
    "ADP": "above at in into of on over to with without after before",
    "INTJ": "hello",
    "NUM": "one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen "
           "sixteen seventeen eighteen nineteen twenty sixty eighty ninety hundred",
    "ADJ": "left right slow quick normal deep full half high low middle long short small seated upper other "
           "idle little quarter",
    "ADV": "ahead afterwards backward backwards back calmly carefully clockwise counterclockwise deeply down "
           "far fast forward quickly slightly slowly still then together up once twice around much out "
           "sideways straight first finally",
}
_NOUNS = {"person": "person", "man": "man", "woman": "woman", "human": "human", "arm": "arm", "arms": "arm",
          "hand": "hand", "hands": "hand", "fist": "fist", "fists": "fist", "foot": "foot", "leg": "leg",
          "knees": "knee", "head": "head", "body": "body", "chair": "chair", "chest": "chest",
          "circle": "circle", "distance": "distance", "height": "height", "line": "line", "pace": "pace",
          "place": "place", "position": "position", "seat": "seat", "shoulder": "shoulder", "side": "side",
          "sides": "side", "times": "time", "way": "way", "waist": "waist", "degrees": "degree",
          "front": "front"}
_VERBS = {"applauds": "applaud", "bends": "bend", "boxes": "box", "brings": "bring", "claps": "clap",
          "does": "do", "faces": "face", "held": "hold", "holds": "hold", "hops": "hop", "jabs": "jab",
          "jogging": "jog", "jogs": "jog", "leaps": "leap", "lifts": "lift", "looks": "look", "lowers": "lower",
          "makes": "make", "moves": "move", "moving": "move", "puts": "put", "raises": "raise", "rises": "rise",
          "runs": "run", "running": "run", "shuffles": "shuffle", "sidesteps": "sidestep", "sits": "sit",
          "spins": "spin", "sprints": "sprint", "stands": "stand", "standing": "stand", "stays": "stay",
          "swings": "swing", "takes": "take", "throws": "throw", "turning": "turn", "walks": "walk",
          "waves": "wave", "alternating": "alternate", "using": "use"}
# NOUN after a determiner, number or adjective ("does two squats"), VERB otherwise ("squats down")
_NOUN_OR_VERB = {"jump": "jump", "jumps": "jump", "kick": "kick", "kicks": "kick", "punch": "punch",
                 "punches": "punch", "squat": "squat", "squats": "squat", "step": "step", "steps": "step",
                 "bow": "bow", "bows": "bow", "turn": "turn", "turns": "turn"}


def _entries(words: dict) -> tuple[dict[str, tuple[str, str]], dict[str, str]]:
    """A word table -> (word -> (lemma, POS), word -> lemma of the words that are a NOUN or a VERB by context).

    A table maps a closed-class tag to a space-separated string of words, "NOUN" / "VERB" to {word: lemma}, and
    "NOUN_OR_VERB" to {word: lemma}."""
    out: dict[str, tuple[str, str]] = {}
    for pos, entry in words.items():
        if pos in ("NOUN", "VERB"):
            out.update({w: (lemma, pos) for w, lemma in entry.items()})
        elif pos != "NOUN_OR_VERB":
            out.update({w: (w, pos) for w in entry.split()})
    return out, dict(words.get("NOUN_OR_VERB", {}))


@functools.cache
def lexicon() -> tuple[dict[str, tuple[str, str]], dict[str, str]]:
    """The whole lexicon: the shared words here and every family module's own WORDS (families.GROUPS), as
    (word -> (lemma, POS), word -> lemma of NOUN-or-VERB words). Built on first use: the family modules
    import this one for their phrasing helpers."""
    from .families import GROUPS

    lex, either = _entries({**_WORDS, "NOUN": _NOUNS, "VERB": _VERBS, "NOUN_OR_VERB": _NOUN_OR_VERB})
    for group in GROUPS:
        more, more_either = _entries(group.WORDS)
        for w, entry in {**more, **{w: (lemma, "?") for w, lemma in more_either.items()}}.items():
            known = lex.get(w) or (either.get(w) and (either[w], "?"))
            if known and known != entry:
                raise ValueError(f"{group.__name__}.WORDS gives {w!r} as {entry}, the lexicon has {known}")
        lex.update(more)
        either.update(more_either)
    return lex, either


def pos_tokens(caption: str) -> str:
    """HumanML3D's token field: 'a person walks forward.' -> 'a/DET person/NOUN walk/VERB forward/ADV'."""
    lex, either = lexicon()
    out, prev = [], None
    for word in caption.lower().replace("-", "").split():
        word = "".join(ch for ch in word if ch.isalpha())
        if not word:
            continue
        if word in either:
            pos = "NOUN" if prev in ("DET", "NUM", "ADJ") else "VERB"
            lemma = either[word]
        elif word in lex:
            lemma, pos = lex[word]
        else:
            raise ValueError(f"caption word {word!r} is not in the procedural POS lexicon: {caption!r}")
        out.append(f"{lemma}/{pos}")
        prev = pos
    return " ".join(out)


def caption_line(caption: str, start: float = 0.0, end: float = 0.0) -> str:
    """One line of a HumanML3D texts/ file: caption#tokens#start#end, in seconds (0.0#0.0: the whole clip).

    Times are rounded to 0.01 s: a frame boundary at 20 fps is a multiple of 0.05 s, which T2M's
    `int(seconds * 20)` reads back as the same frame."""
    return f"{caption}#{pos_tokens(caption)}#{round(float(start), 2)!r}#{round(float(end), 2)!r}"
