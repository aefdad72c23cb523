"""The TCA caption index (mogo_export.export.caption_index): built on the tiny dataset, read back by the runtime."""
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from mogo_export.data.dataset import MotionDataset
from mogo_export.export.caption_index import build_caption_index, tca_manifest_section, training_captions
from mogo_export.models.text_encoder import get_text_encoder
from mogo_runtime import Bundle, MotionGenerator
from mogo_runtime.bundle.folder import sha256_file
from mogo_runtime.tca import CaptionIndex, OfflineAligner
from mogo_runtime.text import TextEncoderSession


@pytest.fixture(scope="module")
def data(tiny_checkpoints) -> Path:
    return tiny_checkpoints.parent / "data"


@pytest.fixture(scope="module")
def encoder(tiny_bundle):
    return get_text_encoder(json.loads((tiny_bundle / "manifest.json").read_text())["text_encoder"]["name"])


@pytest.mark.parametrize("dtype", ["int8", "float16"])
def test_index_round_trips_with_embeddings_of_the_encoder(tmp_path, data, encoder, dtype):
    facts = build_caption_index(data, encoder, tmp_path / "captions.npz", dtype=dtype)
    captions, labels = training_captions(data)
    train = MotionDataset.load(data, "train")
    assert set(captions) == {c for it in train.items for c in it.captions}             # training captions only
    assert len(captions) == len(set(captions)) == facts["count"]
    assert facts == {"file": "captions.npz", "count": len(captions), "dim": encoder.dim, "dtype": dtype,
                     "encoder": encoder.name, "labels": True, "split": "train",
                     "bytes": (tmp_path / "captions.npz").stat().st_size}
    index = CaptionIndex.load(tmp_path / "captions.npz")
    assert index.captions == captions and index.labels == labels and index.encoder == encoder.name
    assert index.dtype == dtype and index.dim == encoder.dim
    fresh = encoder.encode(captions).float().numpy()
    cos = (index.embeddings * fresh).sum(1) / np.linalg.norm(fresh, axis=1)
    assert cos.min() >= 0.99
    with np.load(tmp_path / "captions.npz", allow_pickle=False) as z:                  # no pickles inside
        assert z["embeddings"].dtype == (np.int8 if dtype == "int8" else np.float16)
    per_caption = (tmp_path / "captions.npz").stat().st_size / len(captions)
    assert per_caption < (encoder.dim + 200 if dtype == "int8" else 2 * encoder.dim + 200)   # compact


def test_index_matches_the_runtime_text_encoder(tmp_path, data, encoder, tiny_bundle):
    build_caption_index(data, encoder, tmp_path / "captions.npz")
    index = CaptionIndex.load(tmp_path / "captions.npz")
    session = TextEncoderSession(tiny_bundle / "text_encoder.onnx", tiny_bundle / "tokenizer.json")
    onnx_emb = session.encode(index.captions[:20])
    cos = (index.embeddings[:20] * onnx_emb).sum(1) / np.linalg.norm(onnx_emb, axis=1)
    assert cos.min() >= 0.99
    idx, sims = index.search(onnx_emb, 1)
    assert idx[:, 0].tolist() == list(range(20)) or sims[:, 0].min() >= 0.99           # each finds itself


def test_a_bundle_with_the_index_aligns_prompts(tmp_path, data, encoder, tiny_bundle):
    """What export_bundle writes with the index: the file listed in `files`, a `tca` section; the runtime uses it."""
    bundle_dir = tmp_path / "bundle"
    shutil.copytree(tiny_bundle, bundle_dir)
    facts = build_caption_index(data, encoder, bundle_dir / "captions.npz")
    manifest = json.loads((bundle_dir / "manifest.json").read_text())
    manifest["tca"] = dataclasses.asdict(tca_manifest_section(facts))
    manifest["files"]["captions.npz"] = {"bytes": facts["bytes"], "sha256": sha256_file(bundle_dir / "captions.npz")}
    (bundle_dir / "manifest.json").write_text(json.dumps(manifest))
    assert set(manifest["tca"]) >= {"file", "count", "dtype", "encoder", "lexical_weight", "split_margin"}

    gen = MotionGenerator(Bundle.load(bundle_dir))
    assert isinstance(gen.aligner, OfflineAligner) and gen.aligner.has_index
    caption = gen.aligner.index.captions[0]
    m = gen.generate(caption, seed=0, align=True)
    assert m.aligned_text is not None and m.aligned_text.startswith("a person ")
    assert gen.aligner.align(caption).details["neighbours"][0][0][1] > 0.95     # a training caption finds itself
