"""The MiniLM text encoder: torch vs its ONNX export (fp32 and int8), the runtime session, the cache."""
import json

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from mogo_export.export.text_encoder import export_text_encoder, quantize_text_encoder
from mogo_export.models.text_encoder import (CachedTextEncoder, MiniLMTextEncoder, TextEncoder,
                                             get_text_encoder, register_text_encoder)
from mogo_runtime.text import TextEncoderSession, TokenizerSettings, tokenize

LONG = " ".join(["a person walks forward slowly, then turns left and waves with the right hand."] * 12)
SENTENCES = [
    "a person walks forward", "someone is walking ahead", "a man waves his left hand",
    "the person jumps up and down twice", "a person does a cartwheel", "someone sits down on a chair slowly",
    "a figure raises both arms above the head then lowers them", "a person kicks with the right leg",
    "the man turns around and walks back", LONG,
]


@pytest.fixture(scope="module")
def encoder() -> MiniLMTextEncoder:
    return get_text_encoder("all-MiniLM-L6-v2")


@pytest.fixture(scope="module")
def exported(encoder, tmp_path_factory):
    """One export (~12 s on 2 cores) shared by the tests below."""
    out = tmp_path_factory.mktemp("text_bundle")
    return out, export_text_encoder(encoder, out)


def ort_run(path, ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return sess.run(["text_embedding"], {"input_ids": ids, "attention_mask": mask})[0]


def test_export_describes_symbolic_io_and_metadata(exported):
    out, info = exported
    assert info["inputs"] == [{"name": "input_ids", "dtype": "int64", "shape": ["batch", "sequence"]},
                              {"name": "attention_mask", "dtype": "int64", "shape": ["batch", "sequence"]}]
    assert info["outputs"] == [{"name": "text_embedding", "dtype": "float32", "shape": ["batch", 384]}]
    model = onnx.load(str(out / "text_encoder.onnx"))
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta == info["metadata"]
    assert {k: meta[k] for k in ("encoder", "dim", "pooling", "normalized", "max_length")} == {
        "encoder": "all-MiniLM-L6-v2", "dim": "384", "pooling": "mean", "normalized": "true", "max_length": "256"}
    assert not (out / "text_encoder.onnx.data").exists()          # one self-contained file
    tok = json.loads((out / "tokenizer.json").read_text())
    assert tok["truncation"]["max_length"] == 256                   # not the shipped file's 128
    assert tok["padding"]["strategy"] == "BatchLongest"


def test_fp32_graph_uses_only_default_onnx_domain(exported):
    model = onnx.load(str(exported[0] / "text_encoder.onnx"))
    assert {o.domain for o in model.opset_import} == {""}
    assert {n.domain for n in model.graph.node} == {""}             # no com.microsoft fused ops
    assert len(model.functions) == 0


def test_onnx_matches_torch_on_random_and_real_batches(encoder, exported):
    path = exported[0] / "text_encoder.onnx"
    rng = np.random.default_rng(0)
    worst = 0.0
    for n, s in [(1, 3), (3, 40), (2, 256), (5, 17)]:              # sizes unlike the trace (2, 12)
        lengths = rng.integers(2, s + 1, size=n)
        lengths[0] = s                                              # at least one row fills the batch
        ids = rng.integers(1000, 30000, size=(n, s)).astype(np.int64)
        mask = (np.arange(s)[None, :] < lengths[:, None]).astype(np.int64)
        ids[:, 0] = 101
        ids[np.arange(n), lengths - 1] = 102
        ids[mask == 0] = 0
        with torch.no_grad():
            ref = encoder(torch.from_numpy(ids), torch.from_numpy(mask)).numpy()
        worst = max(worst, float(np.abs(ort_run(path, ids, mask) - ref).max()))
    # real sentences through the runtime session (its own tokenizer.json), incl. a prompt cut at 256 tokens
    sess = TextEncoderSession(path, exported[0] / "tokenizer.json")
    for batch in (SENTENCES[:3], SENTENCES[3:], [LONG, LONG + " " + LONG, "jumps"]):
        worst = max(worst, float(np.abs(sess.encode(batch) - encoder.encode(batch).numpy()).max()))
    print(f"\nONNX fp32 vs torch: max abs diff {worst:.2e}")
    assert worst < 1e-4


def test_long_prompts_are_cut_at_256_not_128(encoder, exported):
    sess = TextEncoderSession(exported[0] / "text_encoder.onnx", exported[0] / "tokenizer.json")
    _, mask = tokenize(sess.tokenizer, [LONG, LONG + " " + LONG])
    assert mask.sum(1).tolist()[1] == 256 and 128 < mask.sum(1)[0] < 256
    assert len(encoder.tokenizer.encode(LONG).ids) == mask[0].sum()  # torch and runtime tokenise alike


def test_semantics(encoder, exported):
    a, b, c = encoder.encode(["a person walks forward", "someone is walking ahead", "a man waves his left hand"])
    assert float(a @ b) > float(a @ c) + 0.2
    assert torch.allclose(a.norm(), torch.tensor(1.0), atol=1e-5)
    x = TextEncoderSession(exported[0] / "text_encoder.onnx", exported[0] / "tokenizer.json").encode(
        ["a person walks forward", "someone is walking ahead", "a man waves his left hand"])
    assert x[0] @ x[1] > x[0] @ x[2] + 0.2


def test_int8_stays_close_to_fp32(exported):
    out = exported[0]
    options = quantize_text_encoder(out / "text_encoder.onnx", out / "text_encoder.int8.onnx", reduce_range=True)
    assert options["per_channel"] is True and options["reduce_range"] is True
    fp32 = TextEncoderSession(out / "text_encoder.onnx", out / "tokenizer.json").encode(SENTENCES)
    int8 = TextEncoderSession(out / "text_encoder.int8.onnx", out / "tokenizer.json").encode(SENTENCES)
    cos = (fp32 * int8).sum(1) / np.linalg.norm(int8, axis=1)
    size = (out / "text_encoder.int8.onnx").stat().st_size / (out / "text_encoder.onnx").stat().st_size
    print(f"\nint8 vs fp32 cosine: min {cos.min():.4f} mean {cos.mean():.4f}; size ratio {size:.2f}")
    assert cos.min() >= 0.98
    assert size < 0.35


class CountingEncoder(TextEncoder):
    def __init__(self, inner: TextEncoder):
        self.inner, self.name, self.dim = inner, inner.name, inner.dim
        self.texts_seen: list[str] = []

    def encode(self, texts):
        self.texts_seen += texts
        return self.inner.encode(texts)


def test_cache_returns_identical_embeddings_without_recomputing(encoder, tmp_path):
    path = tmp_path / "cache" / "captions.npz"
    counting = CountingEncoder(encoder)
    cached = CachedTextEncoder(counting, path)
    first = cached.encode(SENTENCES[:4] + [SENTENCES[0]])            # a duplicate is embedded once
    assert counting.texts_seen == SENTENCES[:4]
    again = cached.encode([SENTENCES[2], SENTENCES[0]])
    assert counting.texts_seen == SENTENCES[:4]                      # nothing recomputed
    assert torch.equal(again, first[[2, 0]])
    assert torch.equal(first[:4], encoder.encode(SENTENCES[:4]))
    assert sorted(p.name for p in path.parent.iterdir()) == ["captions.npz"]   # no temp file left behind

    counting2 = CountingEncoder(encoder)
    reloaded = CachedTextEncoder(counting2, path)                    # a new process reads the file
    mixed = reloaded.encode([SENTENCES[1], SENTENCES[5]])
    assert counting2.texts_seen == [SENTENCES[5]]
    assert torch.equal(mixed[0], first[1]) and len(reloaded) == 5


def test_cache_refuses_another_encoders_file(encoder, tmp_path):
    path = tmp_path / "captions.npz"
    CachedTextEncoder(encoder, path).encode(["a person walks"])
    other = CountingEncoder(encoder)
    other.name = "clip-vit-b32"
    with pytest.raises(ValueError, match="holds embeddings of 'all-MiniLM-L6-v2'"):
        CachedTextEncoder(other, path)


def test_registry_plugs_in_a_custom_encoder():
    class Constant(TextEncoder):
        name, dim = "constant-test", 4

        def encode(self, texts):
            return torch.nn.functional.normalize(torch.ones(len(texts), 4), dim=-1)

    register_text_encoder("constant-test", Constant)
    assert get_text_encoder("constant-test").encode(["x", "y"]).shape == (2, 4)
    with pytest.raises(KeyError, match="unknown text encoder 'nope'"):
        get_text_encoder("nope")
    with pytest.raises(ValueError, match="max_length=600 exceeds"):
        MiniLMTextEncoder(settings=TokenizerSettings(max_length=600))
