"""The offline aligner: normalise the wording, split it into clauses, and condition on the nearest training
caption of each clause, with the bundle's caption index and text encoder only (no generative model).

    aligner = OfflineAligner(bundle, text_session)
    aligner.align("guy starts jogging real quick, then sits").text   # 'a person jogs forward slowly and then ...'

Each clause, as "a person <clause>.", is embedded by the bundle's text encoder and compared (cosine) with the
single-action captions of the index; the best `CANDIDATES` are re-ranked by agreement on direction words
(left/right, forward/backward; `lexical_weight`) and the best one's verb phrase replaces the clause.
"""
from __future__ import annotations

import re
import warnings
from typing import Callable

import numpy as np

from ..bundle.sections import TcaSpec
from ..text import check_texts
from .base import AlignedPrompt, Aligner
from .index import CaptionIndex, load_bundle_index
from .lexicon import DIRECTIONS, OPPOSITES
from .wording import WordingNormalizer, caption_verbs, sentence, strip_subject

# The aligner's settings where the caller gives none and the bundle has no `tca` section: that section's defaults.
DEFAULTS = {"lexical_weight": TcaSpec.lexical_weight, "split_margin": TcaSpec.split_margin}
CANDIDATES = 32   # nearest captions re-ranked by direction words
NEIGHBOURS = 3    # of them, kept per clause in `details["neighbours"]`
# Bare "and"s tried as split points, per prompt (the first ones). Each try embeds a clause and its two parts, so
# trying all of them made a long run-on prompt quadratic: 36.7 s for 3,000 characters (docs/tca.md); 8 per clause
# still let four run-on clauses of MAX_CLAUSE_CHARS take 3 s.
MAX_SPLITS = 8
# Clauses aligned per prompt, and characters per clause; past them a prompt is cut, with a warning. Training
# captions name one to four actions in a few dozen words, and the encoder reads only the first few hundred tokens,
# so more would barely reach the model while every clause costs encoder rows. The bounds also keep the aligned text
# (clauses, or captions of at most index.MAX_TEXT characters, joined) under text.MAX_PROMPT_CHARS.
MAX_CLAUSES = 8
MAX_CLAUSE_CHARS = 500


def _encoder(session) -> Callable[[list[str]], np.ndarray]:
    """Anything that embeds prompts: a TextEncoderSession (.encode), an OrtBackend (.encode_text), a callable."""
    fn = next((getattr(session, name) for name in ("encode", "encode_text") if hasattr(session, name)), session)
    if fn is session and not callable(session):
        raise TypeError(f"text_session must have .encode(list[str]) or .encode_text(list[str]); got "
                        f"{type(session).__name__}")
    return lambda texts: np.asarray(fn(list(texts)), np.float32)


def _cut(text: str, most: int) -> str:
    """`text` cut to at most `most` characters, after its last whole word where it has one there."""
    if len(text) <= most:
        return text
    head = text[:most + 1].rsplit(" ", 1)[0]      # the character past the cut tells if the last word is whole
    return head[:most]


def _query_directions(clause: str) -> set[str]:
    return set(clause.replace("backwards", "backward").split()) & DIRECTIONS


def _caption_directions(caption: str) -> set[str]:
    return set(re.findall(r"[a-z]+", caption.lower().replace("backwards", "backward"))) & DIRECTIONS


def _agreement(query: set[str], caption: set[str]) -> float:
    """+1 per direction word both share, -2 per direction word of the caption that contradicts the query."""
    conflict = sum(1 for w in caption & OPPOSITES.keys() if OPPOSITES[w] in query and w not in query)
    return len(query & caption) - 2.0 * conflict


class OfflineAligner(Aligner):
    """Normalise, split, retrieve: TCA with the bundle's caption index and text encoder, no generative model.

    bundle: a mogo_runtime.Bundle (or None, with `index=` or for wording only); text_session: what embeds
    prompts (the bundle's TextEncoderSession or OrtBackend, or a callable). lexical_weight / split_margin
    default to the manifest's `tca` section, else DEFAULTS. Without a caption index the wording is only
    normalised (method "normalize"), with a warning when the bundle lacks one.
    """

    def __init__(self, bundle=None, text_session=None, lexical_weight: float | None = None,
                 split_margin: float | None = None, index: CaptionIndex | None = None):
        spec = None
        if index is None and bundle is not None:
            index, spec = load_bundle_index(bundle)
        self.index = index
        cfg = {k: getattr(spec, k) for k in DEFAULTS} if spec is not None else DEFAULTS
        self.lexical_weight = float(cfg["lexical_weight"] if lexical_weight is None else lexical_weight)
        self.split_margin = float(cfg["split_margin"] if split_margin is None else split_margin)
        self.encode = _encoder(text_session) if text_session is not None else None
        self._warn_no_index = bundle is not None and index is None
        vocab = verbs = None
        if index is not None:
            if self.encode is None:
                raise ValueError("OfflineAligner with a caption index needs text_session to embed prompts")
            vocab = {w for c in index.captions for w in re.findall(r"[a-z]+", c.lower())}
            verbs = caption_verbs(index.captions)
            single = [not (lb or "").startswith("seq:") for lb in (index.labels or [""] * len(index))]
            self.single_mask = np.array(single, bool)     # a clause is one action: never match a sequence
            if not self.single_mask.any():
                self.single_mask[:] = True
            self._directions: dict[int, set[str]] = {}    # caption row -> its direction words
        self.normalizer = WordingNormalizer(vocab, verbs)

    @property
    def has_index(self) -> bool:
        return self.index is not None

    def align(self, text: str) -> AlignedPrompt:
        """`text` in the captions' style; ValueError for a prompt `check_texts` refuses (over MAX_PROMPT_CHARS
        characters, blank, not Unicode text), so the work stays bounded. Clauses past MAX_CLAUSES, and characters of
        a clause past MAX_CLAUSE_CHARS, are dropped with a warning."""
        check_texts([text])
        clauses = self._bounded(self.normalizer.normalize(text))
        if not clauses:   # nothing recognisable: condition on the prompt as given
            return AlignedPrompt(text, method="none", details={"reason": "no motion words found", "clauses": []})
        if self.index is None:
            if self._warn_no_index:
                warnings.warn("this bundle has no caption index (manifest section 'tca'): TCA only normalises the "
                              "wording; re-export the bundle with a caption index for retrieval", stacklevel=3)
                self._warn_no_index = False
            normalized = sentence(clauses)
            return AlignedPrompt(normalized, method="normalize", details={"clauses": clauses, "normalized": normalized})
        clauses = self._refine_split(clauses)
        idx, cos, _ = self._scores(clauses)
        hits = [list(zip(i.tolist(), c.tolist())) for i, c in zip(idx, cos)]
        clauses, hits = self._merge_repeats(clauses, hits)
        details = {"clauses": clauses, "normalized": sentence(clauses),
                   "neighbours": [[(self.index.captions[i], round(float(s), 4)) for i, s in h] for h in hits]}
        return AlignedPrompt(sentence([strip_subject(self.index.captions[h[0][0]]) for h in hits]),
                             method="nearest", details=details)

    @staticmethod
    def _bounded(clauses: list[str]) -> list[str]:
        cut = []
        if len(clauses) > MAX_CLAUSES:
            cut.append(f"it names {len(clauses)} actions, the first {MAX_CLAUSES} are followed (a timeline, "
                       f"[(prompt, start_seconds), ...], chains more)")
            clauses = clauses[:MAX_CLAUSES]
        if any(len(c) > MAX_CLAUSE_CHARS for c in clauses):
            cut.append(f"an action described in more than {MAX_CLAUSE_CHARS} characters is cut there")
            clauses = [_cut(c, MAX_CLAUSE_CHARS) for c in clauses]
        if cut:
            warnings.warn(f"align: the prompt is cut: {'; '.join(cut)}", stacklevel=3)   # the caller of align()
        return clauses

    # ---- retrieval
    def _scores(self, phrases: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Best re-ranked hits for each phrase: (indices (P, k), cosine (P, k), score (P, k)), best first."""
        q = self.encode([sentence([p]) for p in phrases])
        idx, cos = self.index.search(q, CANDIDATES, self.single_mask)
        score = cos.copy()
        if self.lexical_weight:
            for r, p in enumerate(phrases):
                words = _query_directions(p)
                score[r] += self.lexical_weight * np.array([_agreement(words, self._caption_words(i))
                                                            for i in idx[r]])
        order = np.argsort(-score, axis=1, kind="stable")[:, :NEIGHBOURS]
        return tuple(np.take_along_axis(a, order, axis=1) for a in (idx, cos, score))

    def _caption_words(self, i: int) -> set[str]:
        if i not in self._directions:
            self._directions[i] = _caption_directions(self.index.captions[i])
        return self._directions[i]

    def _merge_repeats(self, clauses, hits):
        """Neighbouring clauses that retrieve the same action family describe one action: keep the closer one."""
        if self.index.labels is None:
            return clauses, hits
        out_c, out_h = [], []
        for c, h in zip(clauses, hits):
            label = self.index.labels[h[0][0]]
            if out_h and label is not None and self.index.labels[out_h[-1][0][0]] == label:
                if h[0][1] > out_h[-1][0][1]:
                    out_c[-1], out_h[-1] = c, h
                continue
            out_c.append(c)
            out_h.append(h)
        return out_c, out_h

    def _refine_split(self, clauses: list[str]) -> list[str]:
        """Split a clause at a bare "and" when its parts each match the captions better than the whole does."""
        out: list[str] = []
        tries = MAX_SPLITS
        for k, c in enumerate(clauses):
            words = c.split()
            room = MAX_CLAUSES - len(out) - (len(clauses) - k)     # a split must not push the count past the bound
            cuts = [i for i, w in enumerate(words) if w == "and" and 0 < i < len(words) - 1
                    and self.normalizer.is_verb(words[i + 1])][:tries if room > 0 else 0]
            tries -= len(cuts)
            best_parts, best = [c], None
            for cut in cuts:
                parts = [" ".join(words[:cut]), " ".join(words[cut + 1:])]
                _, _, score = self._scores([c] + parts)
                whole, split = float(score[0, 0]), float(score[1:, 0].mean())
                if split > whole + self.split_margin and (best is None or split > best):
                    best_parts, best = parts, split
            out += best_parts
        return out
