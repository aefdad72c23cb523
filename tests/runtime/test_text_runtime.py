"""TextEncoderSession without torch: a tiny hand-built tokenizer + ONNX graph (mean of an embedding table)."""
import json

import numpy as np
import onnx
import pytest
from tokenizers import Tokenizer
from toy_bundle import mean_pool_encoder, word_tokenizer

from mogo_runtime.text import TextEncoderSession, TokenizerSettings, configure_tokenizer, tokenize

WORDS = ["a", "person", "walks", "forward", "waves", "hand", "jumps", "twice", "left", "right"]
VOCAB = {"[PAD]": 0, "[UNK]": 1, "[CLS]": 2, "[SEP]": 3, **{w: i + 4 for i, w in enumerate(WORDS)}}
DIM, MAX_LEN = 8, 6
TABLE = np.random.default_rng(0).standard_normal((len(VOCAB), DIM)).astype(np.float32)


def make_tokenizer() -> Tokenizer:
    return word_tokenizer(WORDS)


def make_graph(max_length: int = MAX_LEN) -> onnx.ModelProto:
    return mean_pool_encoder(TABLE, max_length, name="tiny")


def reference(texts: list[str]) -> np.ndarray:
    out = []
    for t in texts:
        ids = [2] + [VOCAB.get(w, 1) for w in t.lower().split()][:MAX_LEN - 2] + [3]
        v = TABLE[ids].mean(0)
        out.append(v / np.linalg.norm(v))
    return np.stack(out)


@pytest.fixture
def bundle(tmp_path):
    configure_tokenizer(make_tokenizer(), TokenizerSettings(max_length=MAX_LEN)).save(str(tmp_path / "tokenizer.json"))
    onnx.save(make_graph(), str(tmp_path / "text_encoder.onnx"))
    return tmp_path


def test_tokenize_truncates_and_pads_to_longest(bundle):
    tok = Tokenizer.from_file(str(bundle / "tokenizer.json"))
    assert TokenizerSettings.from_tokenizer(tok) == TokenizerSettings(max_length=MAX_LEN)
    ids, mask = tokenize(tok, ["a person", "a person walks forward and waves twice"])
    assert ids.dtype == mask.dtype == np.int64
    assert ids.shape == (2, MAX_LEN)                      # longest prompt, cut at max_length incl. [CLS]/[SEP]
    assert ids[1].tolist() == [2, 4, 5, 6, 7, 3]           # 'and' is unknown -> never reached after the cut
    assert ids[0].tolist() == [2, 4, 5, 3, 0, 0]           # right-padded with [PAD]
    assert mask.tolist() == [[1, 1, 1, 1, 0, 0], [1] * 6]
    ids, mask = tokenize(tok, ["a person", "walks"])
    assert ids.shape == (2, 4)                             # padded to the longest in the batch, not to max_length


def test_session_matches_numpy_reference(bundle):
    sess = TextEncoderSession(bundle / "text_encoder.onnx", bundle / "tokenizer.json", threads=1)
    assert (sess.dim, sess.name, sess.settings.max_length) == (DIM, "tiny", MAX_LEN)
    texts = ["a person walks forward", "jumps", "a person jumps twice then waves left hand right hand", "hand"]
    emb = sess.encode(texts)
    assert emb.dtype == np.float32 and emb.shape == (4, DIM)
    np.testing.assert_allclose(emb, reference(texts), atol=1e-6)
    # padding must not leak into the mean: alone == in a batch, and batch_size chunks agree
    np.testing.assert_allclose(sess.encode(["jumps"])[0], emb[1], atol=1e-6)
    np.testing.assert_allclose(sess.encode(texts, batch_size=3), emb, atol=1e-6)


def test_session_rejects_bad_prompts(bundle):
    sess = TextEncoderSession(bundle / "text_encoder.onnx", bundle / "tokenizer.json")
    with pytest.raises(ValueError, match="empty list"):
        sess.encode([])
    with pytest.raises(ValueError, match="prompt 1 is empty or whitespace"):
        sess.encode(["a person walks", "   \t"])
    with pytest.raises(ValueError, match="prompt 0 is empty"):
        sess.encode([""])
    with pytest.raises(ValueError, match="single str"):
        sess.encode("a person walks")
    with pytest.raises(ValueError, match="prompt 0 is a int"):
        sess.encode([3])


def test_session_rejects_unconfigured_or_mismatched_tokenizer(tmp_path, bundle):
    bare = tmp_path / "bare.json"
    make_tokenizer().save(str(bare))                       # no truncation: long prompts would overflow
    with pytest.raises(ValueError, match="no truncation configured"):
        TextEncoderSession(bundle / "text_encoder.onnx", bare)

    fixed = make_tokenizer()
    fixed.enable_truncation(max_length=MAX_LEN)
    fixed.enable_padding(pad_id=0, pad_token="[PAD]", length=128)   # what the shipped MiniLM file does
    fixed.save(str(tmp_path / "fixed.json"))
    with pytest.raises(ValueError, match="longest in batch"):
        TextEncoderSession(bundle / "text_encoder.onnx", tmp_path / "fixed.json")

    onnx.save(make_graph(max_length=MAX_LEN + 1), str(tmp_path / "other.onnx"))
    with pytest.raises(ValueError, match="truncates at 6 tokens but .* max_length=7"):
        TextEncoderSession(tmp_path / "other.onnx", bundle / "tokenizer.json")


def test_configure_tokenizer_writes_settings_into_json(bundle):
    cfg = json.loads((bundle / "tokenizer.json").read_text())
    assert cfg["truncation"]["max_length"] == MAX_LEN
    assert cfg["padding"]["strategy"] == "BatchLongest" and cfg["padding"]["pad_token"] == "[PAD]"
    with pytest.raises(ValueError, match="not in the tokenizer's vocabulary"):
        configure_tokenizer(make_tokenizer(), TokenizerSettings(pad_token="<pad>"))
