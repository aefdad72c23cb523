"""Wording normalisation: a free-form prompt -> ordered caption-style clauses ("jumps in place twice"), rule-based.

The rules live here, the words they use in lexicon.py. Also the helpers that read and write HumanML3D-style
captions: `sentence` (clauses -> "a person X and then Y."), `strip_subject`, `caption_verbs`.
"""
from __future__ import annotations

import re
import unicodedata
from itertools import groupby

from .lexicon import (AFTER, BASE_VERBS, CAPTION_VERB_SKIP, CAUSATIVE, COMPOUND_NOUNS, CONTRACTIONS, COUNTS,
                      DANGLING, DIRECTIONS, EMOJI, FILLER_PHRASES, FILLERS, FUNCTION, HELPERS, IRREGULAR,
                      KEEP_ADVERBS, LEADING_SUBJECT, LIGHT_VERBS, NOUN_VERBS, NUMBERS, PHRASES, SEQ_SPLIT,
                      SUBJECT_IN_CAPTION, SYNONYMS, TIMES, WEAK_VERBS, WORD_MAP)


def _third_person(base: str) -> str:
    if base in ("be", "have"):
        return {"be": "is", "have": "has"}[base]
    if base.endswith(("s", "sh", "ch", "x", "z", "o")):
        return base + "es"
    if base.endswith("y") and len(base) > 1 and base[-2] not in "aeiou":
        return base[:-1] + "ies"
    return base + "s"


def _first_word(text: str) -> str:
    return text.split(None, 1)[0]      # not text.split()[0]: that splits all of a long clause


class WordingNormalizer:
    """Free-form prompt -> ordered clauses (verb phrases, present tense, 3rd person) in the captions' vocabulary.

    `vocabulary`: the words of the training captions (from the caption index): verbs the captions lack are mapped
    through the synonym table, words they never use are dropped. Without it the user's verbs are only conjugated
    and every word is kept. `caption_verbs`: the verbs the captions use (`caption_verbs()`), so that they are
    recognised as verbs.
    """

    def __init__(self, vocabulary: set[str] | None = None, caption_verbs: set[str] | None = None):
        self.vocabulary = set(vocabulary) if vocabulary else None
        verbs = set(SYNONYMS) | set(SYNONYMS.values()) | set(NOUN_VERBS.values())
        verbs = {v for v in verbs if " " not in v} | BASE_VERBS
        if caption_verbs:           # the 3rd-person verbs the captions use (see `caption_verbs`)
            verbs |= {self.base(w, set()) for w in caption_verbs if w.endswith("s") and len(w) > 2}
        # "do", "go", "get", "have" ... count as verbs only when nothing better follows (see _find_verb)
        self.verbs = verbs - HELPERS.difference({"do", "go", "get", "have", "start", "keep"}) - {"is", "has"}

    # ---- word forms
    def base(self, word: str, verbs: set[str] | None = None) -> str:
        """Inflected form -> base form, checked against `verbs` (default: this normaliser's verbs)."""
        verbs = self.verbs if verbs is None else verbs
        if word in IRREGULAR:
            return IRREGULAR[word]
        if word in verbs:
            return word
        cands = []
        if word.endswith("ing") and len(word) > 4:
            stem = word[:-3]
            cands += [stem, stem + "e"] + ([stem[:-1]] if len(stem) > 2 and stem[-1] == stem[-2] else [])
        elif word.endswith(("ied", "ies")) and len(word) > 4:
            cands += [word[:-3] + "y"]
        elif word.endswith("ed") and len(word) > 3:
            stem = word[:-2]
            cands += [stem, word[:-1]] + ([stem[:-1]] if len(stem) > 2 and stem[-1] == stem[-2] else [])
        elif word.endswith("es") and len(word) > 3:
            sibilant = word.endswith(("ses", "shes", "ches", "xes", "zes", "oes"))
            cands += [word[:-2], word[:-1]] if sibilant else [word[:-1], word[:-2]]
        elif word.endswith("s") and not word.endswith("ss") and len(word) > 3:
            cands += [word[:-1]]
        for c in cands:
            if c in verbs:
                return c
        if not verbs and cands:            # building the verb list itself: the plain -s strip
            return cands[0]
        return word

    def is_verb(self, word: str) -> bool:
        return self.base(word) in self.verbs

    def conjugate(self, base: str) -> str:
        """Base -> 3rd person present, mapped into the caption vocabulary through the synonym table if needed."""
        form = _third_person(base)
        if self.vocabulary is None or form in self.vocabulary:   # no index: the user's verb, conjugated
            return form
        target = SYNONYMS.get(base)
        if target is None:
            return form
        head, *rest = target.split()
        return " ".join([_third_person(head)] + rest)

    # ---- text
    def clean(self, text: str) -> str:
        """Lowercase ASCII words and clause punctuation; emojis become words, everything else a space."""
        # emojis stand for actions only when the words name none ("make him 👋"), else they are decoration
        bare = text
        for e in EMOJI:
            bare = bare.replace(e, " ")
        if not self._has_verb(re.sub(r"[^a-z ]", " ", bare.lower())):
            for e, w in EMOJI.items():
                text = text.replace(e, w)
        text = unicodedata.normalize("NFKC", text).lower().replace("’", "'").replace("‘", "'")
        text = "".join(c if (c.isascii() and (c.isalnum() or c in " ',.;!?&+-")) or c == ">" else " " for c in text)
        for pat, rep in CONTRACTIONS:
            text = re.sub(pat, rep, text)
        text = re.sub(r"(?<=[a-z0-9])-(?=[a-z0-9])", " ", text.replace("'", ""))   # "left-footed" -> 2 words
        return re.sub(r"\s+", " ", text).strip()

    def split(self, text: str) -> list[str]:
        """Cleaned text -> raw clauses in temporal order (before any word is changed)."""
        parts = [p.strip() for p in SEQ_SPLIT.split(text) if p and p.strip()]
        out: list[str] = []
        for p in parts:
            m = AFTER.match(p)
            if m and self._has_verb(m.group(2)) and self._has_verb(m.group(1)):
                out += [m.group(2), m.group(1)]            # "wave after you jump": jump first
            else:
                out.append(re.sub(r"^after\s+", "", p))
        return out

    def _has_verb(self, text: str) -> bool:
        return any(self.is_verb(w) for w in text.split())

    def clause(self, raw: str) -> str:
        """One raw clause -> a verb phrase without subject ("jumps in place twice"), or "" if nothing is left."""
        s = f" {raw} "
        for pat in FILLER_PHRASES:
            s = re.sub(pat, " ", s)
        s = re.sub(r"\s+", " ", s).strip()
        s = CAUSATIVE.sub("", s)
        for pat, rep in PHRASES:
            s = re.sub(pat, rep, s)
        s = " ".join(w for w in s.split() if w not in FILLERS)
        for _ in range(3):
            s = CAUSATIVE.sub("", s)
            s = LEADING_SUBJECT.sub("", s)
        # "do a hop" / "give a little wave" / "do 3 jumps": the noun is the action
        words = self._noun_actions(s.split())
        i = self._find_verb(words)
        if i is None:
            words = [w for w in words if w not in HELPERS]
            return " ".join(self._tidy(words, verb_at=None))
        # before the verb: adverbs stay in front; other content ("right leg kick") follows the verb
        lead = [w for w in words[:i] if w in KEEP_ADVERBS]
        moved = [w for w in words[:i] if w not in KEEP_ADVERBS and w not in HELPERS and w not in FUNCTION
                 and not LEADING_SUBJECT.match(w + " ")]
        words = lead + [words[i]] + moved + words[i + 1:]
        return " ".join(self._tidy(words, verb_at=len(lead)))

    def _noun_actions(self, words: list[str]) -> list[str]:
        """"do a lil hop" -> "hop", "do 3 squats" -> "squat three times", "do a left footed kick" -> "kick left"."""
        out, i = [], 0
        while i < len(words):
            w = words[i]
            if w in LIGHT_VERBS and i + 1 < len(words):
                j, count = i + 1, None
                if words[j] in {"a", "an", "one", "some", "the"}:
                    j += 1
                elif words[j] in TIMES or words[j] in {"six", "seven", "eight", "nine", "ten"}:
                    count, j = words[j], j + 1
                kept = []                       # up to 3 modifiers before the noun; direction words are kept
                while j < len(words) and j - i <= 4 and words[j] not in NOUN_VERBS:
                    if words[j] in DIRECTIONS:
                        kept.append(words[j])
                    j += 1
                noun = words[j] if j < len(words) else None
                if noun in NOUN_VERBS and (words[j - 1], noun) not in COMPOUND_NOUNS:
                    out.append(NOUN_VERBS[noun])
                    if count is not None:
                        out.append(TIMES.get(count, f"{count} times"))
                    out += kept
                    i = j + 1
                    continue
            out.append(w)
            i += 1
        return out

    def _find_verb(self, words: list[str]) -> int | None:
        """Index of the action verb: the first motion verb, else the first light one ("takes a seat", "does ...")."""
        first_weak = None
        for i, w in enumerate(words):
            if w in HELPERS and not self.is_verb(w):
                continue
            if (w, words[i + 1] if i + 1 < len(words) else None) in COMPOUND_NOUNS or \
                    (words[i - 1] if i else None, w) in COMPOUND_NOUNS:
                continue
            b = self.base(w)
            if b in self.verbs:
                if b not in WEAK_VERBS:
                    return i
                first_weak = i if first_weak is None else first_weak
        return first_weak

    def _tidy(self, words: list[str], verb_at: int | None) -> list[str]:
        out: list[tuple[str, bool]] = []      # (word, is a verb: never dropped as unknown)
        k = 0
        while k < len(words):
            w = words[k]
            nxt = words[k + 1] if k + 1 < len(words) else None
            if verb_at is not None and (k == verb_at or (k > 0 and words[k - 1] == "and" and self.is_verb(w))):
                out += [(v, True) for v in self.conjugate(self.base(w)).split()]
            elif w in TIMES and nxt == "times":                     # "2 times" -> "twice"
                out.append((TIMES[w], False))
                k += 1
            elif w in WORD_MAP and not (self.vocabulary and w in self.vocabulary):   # never a digit, as NUMBERS
                out.append((WORD_MAP[w], False))
            else:
                out.append((NUMBERS.get(w, w), False))
            k += 1
        if self.vocabulary:
            out = self._drop_unknown(out)
        words = [w for w, _ in out]
        while words and words[-1] in DANGLING:
            words.pop()
        return [w for w, _ in groupby(words)]        # no word twice in a row

    def _drop_unknown(self, words: list[tuple[str, bool]]) -> list[tuple[str, bool]]:
        """Remove content words the captions never use, with the article/preposition run in front of them."""
        out: list[tuple[str, bool]] = []
        for w, verb in words:
            if verb or w in self.vocabulary or w in FUNCTION or w in COUNTS:
                out.append((w, verb))
                continue
            while out and out[-1][0] in FUNCTION and not out[-1][1]:
                out.pop()
        return out

    def normalize(self, text: str) -> list[str]:
        """Free-form prompt -> its clauses as caption-style verb phrases, in order (possibly [] if nothing moves)."""
        clauses = [c for c in (self.clause(c) for c in self.split(self.clean(text))) if c]
        # A clause without a verb ("..., slowly") belongs to its neighbour. Joined at the end: a run of such
        # clauses must not re-copy the growing text at each one.
        out: list[list[str]] = []
        for c in clauses:
            if out and not self.is_verb(_first_word(c)):
                out[-1].append(c)
            elif out and not self.is_verb(_first_word(out[-1][0])):
                out[-1].insert(0, c)       # only ever the first entry: every later one starts with a verb
            else:
                out.append([c])
        return [" ".join(parts) for parts in out]


def caption_verbs(captions: list[str]) -> set[str]:
    """The verbs of training captions: the word after the subject, and after "then" / "after that" / "afterwards"."""
    verbs: set[str] = set()
    for c in captions:
        words = re.findall(r"[a-z]+", strip_subject(c))
        starts = [0] + [i + 1 for i, w in enumerate(words) if w in {"then", "afterwards"} or
                        (w == "that" and i > 0 and words[i - 1] == "after")]
        for i in starts:
            while i < len(words) and words[i] in CAPTION_VERB_SKIP:
                i += 1
            if i < len(words):
                verbs.add(words[i])
    return verbs


def sentence(clauses: list[str], subject: str = "a person") -> str:
    """Verb phrases -> one HumanML3D-style caption: "a person X and then Y and then Z."."""
    return f"{subject} " + " and then ".join(clauses) + "." if clauses else ""


def strip_subject(caption: str) -> str:
    """"a man walks forward slowly." -> "walks forward slowly"."""
    c = caption.strip().rstrip(".").strip()
    c = SUBJECT_IN_CAPTION.sub("", c.lower(), count=1)
    return re.sub(r"^first\s+", "", c)
