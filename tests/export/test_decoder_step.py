"""The decoder_step graph (docs/bundle.md, "decoder_step"): the causal decoder over the tokens that are new, its state
explicit. Its frames are the whole-clip decoder's within float32 rounding; a token's frames are the same bits however
many tokens a call feeds and whoever else is in the batch (what lets a crowd, a lone stream and a decode-only client
agree bit for bit); every variant has it. And the portable step's cache writes, rewritten from ScatterElements to
ScatterND (export/portable.py), compute the same bits.
"""
import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from random_tiny import random_tiny_bundle

from mogo_export.export.graphs import export_module
from mogo_export.export.portable import FixedCacheStepGraph, scatter_nd_writes
from mogo_runtime.bundle import Bundle


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return random_tiny_bundle(tmp_path_factory)


def sessions(bundle: Bundle, variant: str, graphs=("lookup", "decoder", "decoder_step")):
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    return [ort.InferenceSession(bundle.read_verified(bundle.manifest.graph_file(g, variant).file), so,
                                 providers=["CPUExecutionProvider"]) for g in graphs]


def stepped(step, latent, chunk, state_shapes):
    """Decode latent (B, T, C) `chunk` tokens per call from zero state -> features (B, T * ds, D)."""
    state = [np.zeros((len(latent), *s), np.float32) for s in state_shapes]
    out = []
    for t in range(0, latent.shape[1], chunk):
        features, *state = step.run(None, {"latent": latent[:, t:t + chunk],
                                           **{f"decoder_state.{i}": s for i, s in enumerate(state)}})
        out.append(features)
    return np.concatenate(out, 1)


@pytest.mark.parametrize("variant", ["fp32", "compact", "portable_ort"])
def test_decoder_step_gives_the_whole_clip_decoders_frames(tiny, variant):
    bundle = Bundle.load(tiny["bundle"])
    shapes = bundle.manifest.decoder_state
    assert shapes and all(len(s) == 2 and min(s) >= 1 for s in shapes)
    assert all("decoder_step" in graphs for graphs in bundle.manifest.variants.values())
    lookup, decoder, step = sessions(bundle, variant)
    tokens = np.random.default_rng(3).integers(0, bundle.dims.codebook_size, (3, 23, bundle.dims.num_levels))
    (latent,) = lookup.run(None, {"tokens": tokens})
    (whole,) = decoder.run(None, {"latent": latent})
    one = stepped(step, latent, 1, shapes)
    worst = np.abs(one - whole).max() / np.abs(whole).max()
    print(f"decoder_step ({variant}) vs the whole-clip decoder: max |diff| {np.abs(one - whole).max():.2e} "
          f"(relative {worst:.2e})")
    assert one.shape == whole.shape and worst < 1e-5
    for chunk in (2, 5, 23):      # the same bits at any chunk ...
        assert np.array_equal(stepped(step, latent, chunk, shapes), one), chunk
    for row in range(3):          # ... and alone or in a batch
        assert np.array_equal(stepped(step, latent[row:row + 1], 1, shapes)[0], one[row]), row


def test_decoder_step_state_is_what_a_later_frame_needs(tiny):
    """A state carried from earlier tokens changes the next frames; zeros are a motion's start (the whole decode's
    left padding), so a stream started from another clip's state differs from one started fresh."""
    bundle = Bundle.load(tiny["bundle"])
    lookup, decoder, step = sessions(bundle, "fp32")
    tokens = np.random.default_rng(4).integers(0, bundle.dims.codebook_size, (1, 12, bundle.dims.num_levels))
    (latent,) = lookup.run(None, {"tokens": tokens})
    shapes = bundle.manifest.decoder_state
    fresh = stepped(step, latent[:, 6:], 1, shapes)
    (tail,) = decoder.run(None, {"latent": latent[:, 6:]})
    assert np.abs(fresh - tail).max() < 1e-5 * np.abs(tail).max()
    (whole,) = decoder.run(None, {"latent": latent})
    carried = stepped(step, latent, 1, shapes)[:, 6 * bundle.dims.downsample:]
    assert np.abs(carried - fresh).max() > 1e-3          # the state is read
    assert np.abs(carried - whole[:, 6 * bundle.dims.downsample:]).max() < 1e-5 * np.abs(whole).max()


def test_the_portable_step_writes_its_cache_with_scatter_nd_exactly(tiny, tmp_path):
    """The rewrite (ScatterElements -> ScatterND) gives the same bits as the exported graph, and a position past
    the capacity is still an error."""
    tr = tiny["tr"]
    c, capacity = tr.cfg, 9
    L, H, hd = c.num_levels, c.n_heads, c.d_model // c.n_heads
    g = torch.Generator().manual_seed(0)
    text, tokens = torch.randn(2, c.text_dim, generator=g), torch.randint(0, c.codebook_size, (2, 1, L), generator=g)
    past = [torch.randn(2, L * H, capacity, hd, generator=g) for _ in range(2 * c.n_layers)]
    control = [torch.randn(2, 1, c.control_dim, generator=g)] if c.control_dim else []
    names_in = ["text_embedding", "tokens"] + (["control"] if control else []) + ["position"] + \
        [f"past_key_values.{i}.{kv}" for i in range(c.n_layers) for kv in ("key", "value")]
    names_out = ["logits"] + [f"present.{i}.{kv}" for i in range(c.n_layers) for kv in ("key", "value")]
    batch = torch.export.Dim("batch", min=1, max=1024)
    path = tmp_path / "step.onnx"
    export_module(FixedCacheStepGraph(tr, capacity), (text, tokens, *control, torch.tensor([3, 5]), *past), path,
                  names_in, names_out, ({0: batch}, {0: batch}, tuple({0: batch} for _ in names_in[2:])), 17, {})
    exported = onnx.load(str(path))
    assert [n.op_type for n in exported.graph.node].count("ScatterElements") == 2 * c.n_layers
    rewritten = scatter_nd_writes(onnx.load(str(path)), L * H, hd)
    ops = [n.op_type for n in rewritten.graph.node]
    assert "ScatterElements" not in ops and ops.count("ScatterND") == 2 * c.n_layers
    a, b = (ort.InferenceSession(m.SerializeToString(), providers=["CPUExecutionProvider"]) for m in (exported, rewritten))
    rng = np.random.default_rng(5)
    for rows, positions in ((1, [0]), (4, [0, 3, capacity - 1, 5])):
        feed = {"text_embedding": rng.standard_normal((rows, c.text_dim)).astype(np.float32),
                "tokens": rng.integers(0, c.codebook_size, (rows, 1, L)), "position": np.array(positions, np.int64),
                **({"control": rng.standard_normal((rows, 1, c.control_dim)).astype(np.float32)} if control else {}),
                **{n: rng.standard_normal((rows, L * H, capacity, hd)).astype(np.float32) for n in names_in
                   if n.startswith("past")}}
        for x, y in zip(a.run(None, feed), b.run(None, feed)):
            assert np.array_equal(x, y)
    feed["position"] = np.array([0, 1, capacity, 2], np.int64)
    with pytest.raises(Exception, match="ScatterND|indice"):
        b.run(None, feed)
