"""The bundle's tokenizer.json (HuggingFace `tokenizers`), re-implemented for the pieces mogo bundles use, so a device
installs no tokenizers library (with its network clients: huggingface_hub, hf-xet, httpx; 40 MB).

A prompt must reach the text encoder as the same ids the `tokenizers` library gives (the exporter embeds training
captions with it), so each step follows tokenizers' Rust code, as js/src/tokenizer.js does rule for rule: added
tokens ([CLS], [SEP], ... typed in the text) are split out first, the rest is normalised (BertNormalizer: clean text,
space around CJK ideographs, NFD + drop non-spacing marks, per-character lowercase), pre-tokenised (BERT: split on
whitespace, isolate punctuation), cut into WordPiece sub-words (greedy longest match, `##` continuation, [UNK] for a
word with no split or longer than max_input_chars_per_word), cut to max_length minus the template's special tokens,
wrapped in the template ([CLS] A [SEP]) and padded on the right to the longest prompt of the batch. The surface is
the library's, as far as mogo_runtime.text uses it (`encode_batch`, `truncation`, `padding`, `token_to_id`), so
text.py reads both alike; tests/runtime/test_tokenizer.py holds the two to the same ids on over a thousand strings
and every code point.

    tok = Tokenizer.from_str(Path("bundle/tokenizer.json").read_text())
    tok.encode_batch(["a person walks"])[0].ids      # [101, 1037, 2711, 7365, 102]
"""
from __future__ import annotations

import json
import re
import unicodedata
from dataclasses import dataclass
from typing import Callable

from . import unicode_tables as tables
from .checks import shown

# The parts this tokenizer implements (and js/src/tokenizer.js): others are refused before any prompt is read, with
# the field named (a Replace normalizer that expands a character 200,000-fold once aborted a process on a long prompt).
PARTS = {"normalizer": {"BertNormalizer", "Lowercase", "StripAccents", "NFC", "NFD", "NFKC", "NFKD", "Sequence"},
         "pre_tokenizer": {"BertPreTokenizer", "Whitespace", "WhitespaceSplit", "Sequence"},
         "model": {"WordPiece", "WordLevel"},
         "post_processor": {"BertProcessing", "TemplateProcessing"}}


def _members(table: str) -> str:
    """The inside of a regex character set, from a table of space-separated hex code points and ranges."""
    return "".join("-".join(re.escape(chr(int(h, 16))) for h in r.split("-")) for r in table.split())


def _char_class(table: str) -> str:
    return f"[{_members(table)}]"


# tokenizers' own character classes (read off the library by js/scripts/make_unicode_tables.py): Python's
# unicodedata knows another Unicode version, and Rust's char::is_whitespace and the regex crate's \w are not re's
OTHER = re.compile(_char_class(tables.OTHER))
PUNCTUATION = re.compile(f"({_char_class(tables.PUNCTUATION)})")   # re.split keeps each one
NONSPACING_MARK = re.compile(_char_class(tables.NONSPACING_MARK))
WHITESPACE = re.compile(_char_class(tables.WHITESPACE))
WHITESPACE_RUNS = re.compile(_char_class(tables.WHITESPACE) + "+")
# the Whitespace pre-tokenizer's `\w+|[^\w\s]+`
WHITESPACE_PRETOKENS = re.compile(f"{_char_class(tables.WORD)}+|"
                                  f"[^{_members(tables.WORD)}{_members(tables.WHITESPACE)}]+")
CJK = re.compile(_char_class("4e00-9fff 3400-4dbf 20000-2a6df 2a700-2b73f 2b740-2b81f 2b920-2ceaf f900-faff "
                             "2f800-2fa1f"))
MARK = re.compile(_char_class(tables.MARK))


@dataclass(frozen=True)
class Encoding:
    ids: list[int]
    attention_mask: list[int]


class Tokenizer:
    """A tokenizer.json (parsed) whose parts are all in PARTS; ValueError naming the field for anything else."""

    def __init__(self, spec: dict, source: str = "tokenizer.json"):
        def fail(field: str, message: str):
            raise ValueError(f"{source}: {field}: {message}")

        if not isinstance(spec, dict):
            fail("(top level)", "expected a JSON object")
        check_parts(spec, source)
        self.source = source
        self._normalize = _normalizer(spec.get("normalizer"))
        self._pre_tokenize = _pre_tokenizer(spec.get("pre_tokenizer"))
        self._vocab, self._tokenize_word = _model(spec.get("model"), fail)
        added = _added_tokens(spec.get("added_tokens") or [], fail)
        self._added_ids = {content: tid for content, tid, _ in added}
        self._added_raw = _added_pattern([t for t in added if not t[2]])
        self._added_normalized = _added_pattern([t for t in added if t[2]])
        self._before, self._after = _template(spec.get("post_processor"), fail)
        self.truncation, self.padding = _settings(spec, fail, len(self._before) + len(self._after))

    @classmethod
    def from_str(cls, text: str, source: str = "tokenizer.json") -> "Tokenizer":
        try:
            spec = json.loads(text)
        except (json.JSONDecodeError, RecursionError) as e:
            raise ValueError(f"{source}: not a tokenizer.json ({type(e).__name__})") from None
        return cls(spec, source)

    def token_to_id(self, token: str) -> int | None:
        return self._vocab.get(token)

    def encode(self, text: str) -> list[int]:
        """One prompt -> ids, truncated and wrapped in the template (no padding)."""
        ids: list[int] = []
        for piece in _split_added(text, self._added_raw, self._added_ids):
            if isinstance(piece, int):
                ids.append(piece)
                continue
            for inner in _split_added(self._normalize(piece), self._added_normalized, self._added_ids):
                if isinstance(inner, int):
                    ids.append(inner)
                else:
                    for word in self._pre_tokenize(inner):
                        ids += self._tokenize_word(word)
        room = max(0, self.truncation["max_length"] - len(self._before) - len(self._after))
        return self._before + ids[:room] + self._after

    def encode_batch(self, texts: list[str]) -> list[Encoding]:
        """Prompts -> encodings padded on the right to the longest (rounded up to pad_to_multiple_of when set)."""
        rows = [self.encode(t) for t in texts]
        width = max((len(r) for r in rows), default=0)
        multiple = self.padding["pad_to_multiple_of"]
        if multiple:
            width = -(-width // multiple) * multiple
        pad = self.padding["pad_id"]
        return [Encoding(r + [pad] * (width - len(r)), [1] * len(r) + [0] * (width - len(r))) for r in rows]


def check_parts(spec: dict, source: str) -> None:
    """Each normalizer, pre-tokenizer, model and post-processor in `spec` (Sequences walked) is one of PARTS, and
    added tokens are plain (the matching rules of single_word / lstrip / rstrip are implemented by neither runtime)."""
    for i, t in enumerate(spec.get("added_tokens") or []):
        flags = [f for f in ("single_word", "lstrip", "rstrip") if isinstance(t, dict) and t.get(f)]
        if flags:
            raise ValueError(f"{source}: added_tokens[{i}].{flags[0]} is true; this runtime reads plain added tokens")
    parts = [(key, spec.get(key)) for key in PARTS]
    while parts:
        key, part = parts.pop()
        if part is None and key != "model":
            continue
        kind = part.get("type") if isinstance(part, dict) else None
        if not isinstance(kind, str) or kind not in PARTS[key]:
            raise ValueError(f"{source}: {key} {shown(kind)} is not one this runtime reads (it reads "
                             f"{', '.join(sorted(PARTS[key]))})")
        if kind == "Sequence":
            inner = part.get("normalizers" if key == "normalizer" else "pretokenizers")
            parts += [(key, p) for p in inner] if isinstance(inner, list) else [(key, False)]


def _settings(spec: dict, fail, added: int) -> tuple[dict, dict]:
    """truncation and padding as the library's Python properties give them (lowercase directions, `length` None for
    padding to the longest), so TokenizerSettings.from_tokenizer reads both tokenizers alike."""
    trunc, pad = spec.get("truncation"), spec.get("padding")
    truncation = padding = None
    if isinstance(trunc, dict):
        if not isinstance(trunc.get("max_length"), int) or trunc["max_length"] < added:
            fail("truncation.max_length", f"expected an integer >= {added}, got {shown(trunc.get('max_length'))}")
        truncation = {"max_length": trunc["max_length"], "stride": trunc.get("stride", 0),
                      "strategy": "longest_first", "direction": str(trunc.get("direction", "Right")).lower()}
    if isinstance(pad, dict):
        if not isinstance(pad.get("pad_id"), int):
            fail("padding.pad_id", "expected an integer")
        strategy = pad.get("strategy")
        length = strategy.get("Fixed") if isinstance(strategy, dict) else None
        if strategy != "BatchLongest" and length is None:
            fail("padding.strategy", f"expected 'BatchLongest' or {{'Fixed': n}}, got {shown(strategy)}")
        padding = {"length": length, "pad_to_multiple_of": pad.get("pad_to_multiple_of"), "pad_id": pad["pad_id"],
                   "pad_token": pad.get("pad_token", "[PAD]"), "pad_type_id": pad.get("pad_type_id", 0),
                   "direction": str(pad.get("direction", "Right")).lower()}
    return truncation, padding


# ---- added tokens -------------------------------------------------------------------------------------------

def _added_tokens(items, fail) -> list[tuple[str, int, bool]]:
    if not isinstance(items, list):
        fail("added_tokens", "expected a list")
    out = []
    for i, t in enumerate(items):
        if not (isinstance(t, dict) and isinstance(t.get("content"), str) and t["content"]
                and isinstance(t.get("id"), int)):
            fail(f"added_tokens[{i}]", "expected {id, content}")
        out.append((t["content"], t["id"], bool(t.get("normalized"))))
    return out


def _added_pattern(tokens: list[tuple[str, int, bool]]) -> re.Pattern | None:
    """One regex for the tokens: at each position the leftmost match, and of those the longest (longest first)."""
    if not tokens:
        return None
    return re.compile("|".join(re.escape(t[0]) for t in sorted(tokens, key=lambda t: -len(t[0]))))


def _split_added(text: str, pattern: re.Pattern | None, ids: dict[str, int]) -> list[str | int]:
    """`text` split around occurrences of the added tokens: pieces of text and token ids."""
    if pattern is None:
        return [text]
    pieces: list[str | int] = []
    last = 0
    for m in pattern.finditer(text):
        if m.start() > last:
            pieces.append(text[last:m.start()])
        pieces.append(ids[m.group(0)])
        last = m.end()
    if last < len(text):
        pieces.append(text[last:])
    return pieces


# ---- normalizers --------------------------------------------------------------------------------------------

def _clean_text(s: str) -> str:
    s = re.sub(r"[\t\n\r]", " ", s)
    s = OTHER.sub("", s.replace("\0", "").replace("\ufffd", ""))
    return WHITESPACE.sub(" ", s)


def _lowercase(s: str) -> str:
    # Rust lowercases character by character (no context: a final capital sigma becomes σ, not ς)
    return "".join(c.lower() for c in s)


def _normalizer(spec) -> Callable[[str], str]:
    if spec is None:
        return lambda s: s
    kind = spec["type"]
    if kind == "BertNormalizer":
        lowercase = spec.get("lowercase", True)
        steps = []
        if spec.get("clean_text", True):
            steps.append(_clean_text)
        if spec.get("handle_chinese_chars", True):
            steps.append(lambda s: CJK.sub(lambda m: f" {m.group(0)} ", s))
        strip = spec.get("strip_accents")
        if lowercase if strip is None else strip:        # null: as lowercase
            steps.append(lambda s: NONSPACING_MARK.sub("", unicodedata.normalize("NFD", s)))
        if lowercase:
            steps.append(_lowercase)
        return lambda s: _chain(steps, s)
    if kind == "Lowercase":
        return _lowercase
    if kind == "StripAccents":
        return lambda s: MARK.sub("", s)                 # every combining mark, unlike BERT's
    if kind in ("NFD", "NFC", "NFKD", "NFKC"):
        return lambda s: unicodedata.normalize(kind, s)
    parts = [_normalizer(n) for n in spec["normalizers"]]   # a Sequence (check_parts let no other type through)
    return lambda s: _chain(parts, s)


def _chain(steps, s: str) -> str:
    for step in steps:
        s = step(s)
    return s


# ---- pre-tokenizers -----------------------------------------------------------------------------------------

def _pre_tokenizer(spec) -> Callable[[str], list[str]]:
    if spec is None:
        return lambda s: [s] if s else []
    kind = spec["type"]
    if kind == "BertPreTokenizer":
        return lambda s: [p for chunk in _split_whitespace(s) for p in PUNCTUATION.split(chunk) if p]
    if kind == "Whitespace":
        return lambda s: WHITESPACE_PRETOKENS.findall(s)
    if kind == "WhitespaceSplit":
        return _split_whitespace
    parts = [_pre_tokenizer(p) for p in spec["pretokenizers"]]   # a Sequence

    def sequence(s: str) -> list[str]:
        words = [s]
        for p in parts:
            words = [w for word in words for w in p(word)]
        return words
    return sequence


def _split_whitespace(s: str) -> list[str]:
    return [w for w in WHITESPACE_RUNS.split(s) if w]


# ---- models -------------------------------------------------------------------------------------------------

def _model(spec, fail) -> tuple[dict, Callable[[str], list[int]]]:
    """A WordLevel or WordPiece model (check_parts let no other type through): (vocab, word -> ids)."""
    vocab = spec.get("vocab")
    if not isinstance(vocab, dict) or not all(isinstance(v, int) for v in vocab.values()):
        fail("model.vocab", "expected an object of token -> id")
    unk = vocab.get(spec.get("unk_token"))
    if unk is None:
        fail("model.unk_token", f"{shown(spec.get('unk_token'))} is not in the vocabulary")
    if spec["type"] == "WordLevel":
        return vocab, lambda word: [vocab.get(word, unk)]
    prefix = spec.get("continuing_subword_prefix", "##")
    max_chars = spec.get("max_input_chars_per_word", 100)
    return vocab, lambda word: _word_piece(word, vocab, prefix, max_chars, unk)


def _word_piece(word: str, vocab: dict, prefix: str, max_chars: int, unk: int) -> list[int]:
    """Greedy longest-match-first sub-words; [UNK] for the whole word when any part has no match."""
    if len(word) > max_chars:
        return [unk]
    ids, start = [], 0
    while start < len(word):
        for end in range(len(word), start, -1):
            tid = vocab.get((prefix if start else "") + word[start:end])
            if tid is not None:
                break
        else:
            return [unk]
        ids.append(tid)
        start = end
    return ids


# ---- post-processor -----------------------------------------------------------------------------------------

def _template(spec, fail) -> tuple[list[int], list[int]]:
    """The single-sequence template: the ids before and after the content."""
    before: list = []
    after: list = []
    if spec is None:
        pass
    elif spec["type"] == "BertProcessing":
        before, after = [(spec.get("cls") or [None, None])[1]], [(spec.get("sep") or [None, None])[1]]
    else:                                                 # TemplateProcessing
        single = spec.get("single") or []
        seqs = [i for i, p in enumerate(single) if isinstance(p, dict) and "Sequence" in p]
        if len(seqs) != 1:
            fail("post_processor.single", "expected one Sequence")

        def ids(p):
            name = (p.get("SpecialToken") or {}).get("id") if isinstance(p, dict) else None
            tok = (spec.get("special_tokens") or {}).get(name)
            if not isinstance(tok, dict):
                fail("post_processor.single", f"special token {shown(name)} is not in special_tokens")
            return tok.get("ids") or []
        before = [i for p in single[:seqs[0]] for i in ids(p)]
        after = [i for p in single[seqs[0] + 1:] for i in ids(p)]
    if not all(isinstance(i, int) for i in before + after):
        fail("post_processor", "special token ids must be integers")
    return before, after
