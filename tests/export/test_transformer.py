"""RQHC-Transformer: KV-cached step == full forward, level streams, PnQ prefix, relative attention, loss."""
import pytest
import torch
import torch.nn.functional as F

from mogo_export.models.transformer import RQHCTransformer, TransformerConfig
from mogo_export.presets import NAMES, get_preset


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _model(seed=0, **kw):
    torch.manual_seed(seed)
    return RQHCTransformer(get_preset("tiny").transformer_config(**kw)).eval()


def _tokens(cfg: TransformerConfig, B: int, S: int, seed=1):
    g = torch.Generator().manual_seed(seed)
    tok = torch.randint(0, cfg.codebook_size, (B, S, cfg.num_levels), generator=g)
    tok[:, 0] = cfg.bos_id
    return tok


def test_special_ids_and_the_one_2d_embedding_table():
    cfg = get_preset("tiny").transformer_config()
    K, L = cfg.codebook_size, cfg.num_levels
    assert (cfg.end_id, cfg.bos_id, cfg.pad_id) == (K, K + 1, K + 2)
    m = RQHCTransformer(cfg)
    assert m.tok_emb.weight.shape == (L * (K + 3), cfg.d_model)
    assert m.head.out_features == K + 1
    # every weight a MatMul or Gather reads is at most 2-D (int8 per-channel quantization needs it)
    assert max(p.dim() for p in m.parameters()) <= 2
    assert m.param_count() == sum(p.numel() for p in m.parameters())


@pytest.mark.parametrize("S", [3, 9, 20])
def test_step_by_step_equals_full_forward(S):
    """Lengths below, at and far beyond the relative-distance clip (max_rel_dist=8)."""
    m = _model()
    cfg = m.cfg
    B = 2
    text, tok = torch.randn(B, cfg.text_dim), _tokens(cfg, B, S)
    with torch.no_grad():
        full = m(text, tok)  # (B, S, L, K+1)
        assert full.shape == (B, S, cfg.num_levels, cfg.codebook_size + 1)
        past, steps = m.empty_past(B), []
        for j in range(S):
            logits, past = m.step(text, tok[:, j:j + 1], past)
            steps.append(logits)
    torch.testing.assert_close(torch.cat(steps, dim=1), full, atol=1e-5, rtol=0)
    H, hd = cfg.n_heads, cfg.d_model // cfg.n_heads
    assert len(past) == cfg.n_layers
    assert all(k.shape == v.shape == (B * cfg.num_levels, H, S, hd) for k, v in past)


def test_chunked_prefill_equals_full_forward():
    m = _model()
    cfg = m.cfg
    B, S = 3, 20
    text, tok = torch.randn(B, cfg.text_dim), _tokens(cfg, B, S)
    with torch.no_grad():
        full = m(text, tok)
        for chunks in ([5, 1, 7, 7], [12, 8], [1, 19]):
            past, outs, at = m.empty_past(B), [], 0
            for n in chunks:
                logits, past = m.step(text, tok[:, at:at + n], past)
                outs.append(logits)
                at += n
            torch.testing.assert_close(torch.cat(outs, dim=1), full, atol=1e-5, rtol=0)


def test_the_bundle_cache_layout_gives_the_same_logits_and_folded_presents():
    """Caches folded as [batch, L*H, P, hd] (the bundle's layout) are the model's rows, regrouped."""
    m = _model()
    cfg = m.cfg
    B, S, L, H, hd = 2, 11, cfg.num_levels, cfg.n_heads, cfg.d_model // cfg.n_heads
    text, tok = torch.randn(B, cfg.text_dim), _tokens(cfg, B, S)
    with torch.no_grad():
        past, folded = m.empty_past(B), [(k.reshape(B, L * H, 0, hd), v.reshape(B, L * H, 0, hd))
                                         for k, v in m.empty_past(B)]
        for j in range(S):
            want, past = m.step(text, tok[:, j:j + 1], past)
            got, folded = m.step(text, tok[:, j:j + 1], folded)
            torch.testing.assert_close(got, want, atol=0, rtol=0)
    for (k, v), (fk, fv) in zip(past, folded):
        assert fk.shape == fv.shape == (B, L * H, S, hd)
        torch.testing.assert_close(fk, k.reshape(B, L * H, S, hd), atol=0, rtol=0)
        torch.testing.assert_close(fv, v.reshape(B, L * H, S, hd), atol=0, rtol=0)


def test_time_causality_and_level_streams():
    """Stream l reads levels 0..l: a level-l token changes no stream below l and no earlier step."""
    m = _model(num_levels=3)
    cfg = m.cfg
    text, tok = torch.randn(2, cfg.text_dim), _tokens(cfg, 2, 10)
    with torch.no_grad():
        base = m(text, tok)
        for pos, lvl in ((4, 0), (4, 1), (6, 2)):
            tok2 = tok.clone()
            tok2[:, pos, lvl] = (tok2[:, pos, lvl] + 1) % cfg.codebook_size
            diff = (m(text, tok2) - base).abs().amax(dim=(0, 3))  # (S, L)
            assert diff[:pos].max() == 0, "an earlier step changed"
            assert lvl == 0 or diff[:, :lvl].max() == 0, "a coarser level stream changed"
            assert diff[pos, lvl:].min() > 1e-6, "streams >= the level must see it at once"
            assert diff[pos:, lvl:].min() > 0


def test_input_is_the_prefix_at_bos_and_the_level_cumsum_after():
    m = _model(num_levels=3)
    cfg = m.cfg
    K3, B, S, L = cfg.vocab_size, 2, 4, cfg.num_levels
    text, tok = torch.randn(B, cfg.text_dim), _tokens(cfg, B, S)
    with torch.no_grad():
        x = m._inputs(text, tok)[0].view(B, L, S, -1)  # rows b*L + l
        prefix = m.cond_proj(text)  # (B, C)
        for l in range(L):
            torch.testing.assert_close(x[:, l, 0], prefix + m.q_emb[l])  # PnQ, eq. 7
            emb = sum(m.tok_emb.weight[i * K3 + tok[:, 1:, i]] for i in range(l + 1))  # (B, S-1, C), eq. 8
            torch.testing.assert_close(x[:, l, 1:], emb)


def test_text_conditions_every_step_and_zero_text_is_the_null_condition():
    m = _model(cond_drop_prob=1.0, dropout=0.0)
    cfg = m.cfg
    tok = _tokens(cfg, 2, 12)
    t1, t2 = torch.randn(2, cfg.text_dim), torch.randn(2, cfg.text_dim)
    with torch.no_grad():
        assert (m(t1, tok) - m(t2, tok)).abs().amax(dim=(0, 2, 3)).min() > 1e-6  # every step sees the text
        null = m(torch.zeros_like(t1), tok)
        m.train()  # with cond_drop_prob=1 training always sees the null condition
        torch.testing.assert_close(m(t1, tok), null)


def test_distances_beyond_the_clip_look_alike():
    """Distances are clipped at max_rel_dist: with one layer, shuffling the steps that all lie farther back
    than the clip leaves the last step unchanged (attention is order-free among equal distances), while
    a step that sees them within the clip does change."""
    m = _model(n_layers=1)
    cfg = m.cfg
    R = cfg.max_rel_dist
    text = torch.randn(1, cfg.text_dim)
    tok = _tokens(cfg, 1, 30)
    with torch.no_grad():
        full = m(text, tok)
        tok2 = tok.clone()
        far = torch.arange(1, 30 - R - 1)  # steps more than R back from the last step
        tok2[:, far] = tok[:, far.flip(0)]
        torch.testing.assert_close(m(text, tok2)[:, -1], full[:, -1], atol=1e-5, rtol=0)
        assert (m(text, tok2)[:, far.min() + 3] - full[:, far.min() + 3]).abs().max() > 1e-6


def test_loss_masks_padding_and_matches_cross_entropy():
    m = _model()
    cfg = m.cfg
    B, S, L, K = 3, 7, cfg.num_levels, cfg.codebook_size
    lengths = torch.tensor([6, 3, 1])  # motion tokens per sample: 6 -> all S = 7 positions count
    g = torch.Generator().manual_seed(0)
    codes = torch.randint(0, K, (B, S, L), generator=g)
    tok_in = torch.full((B, S, L), cfg.pad_id)
    tgt = torch.full((B, S, L), cfg.pad_id)
    for b, T in enumerate(lengths.tolist()):
        tok_in[b, 0], tok_in[b, 1:T + 1] = cfg.bos_id, codes[b, :T]
        tgt[b, :T], tgt[b, T] = codes[b, :T], cfg.end_id
    text = torch.randn(B, cfg.text_dim)
    with torch.no_grad():
        loss, stats = m.loss(text, tok_in, tgt, lengths)
        logits = m(text, tok_in)
        ces = [F.cross_entropy(logits[b, :T + 1].flatten(0, 1), tgt[b, :T + 1].flatten(), reduction="sum")
               for b, T in enumerate(lengths.tolist())]
        torch.testing.assert_close(loss, sum(ces) / ((lengths + 1).sum() * L))
        assert 0 <= stats["acc"] <= 1 and stats["acc_per_level"].shape == (L,)
        # whatever sits in the padding changes nothing
        tok_in2, tgt2 = tok_in.clone(), tgt.clone()
        tok_in2[1, 4:], tgt2[1, 4:] = 5, 7
        torch.testing.assert_close(m.loss(text, tok_in2, tgt2, lengths)[0], loss)


def test_a_few_optimiser_steps_lower_the_loss():
    torch.manual_seed(0)
    m = RQHCTransformer(get_preset("tiny").transformer_config(dropout=0.0, cond_drop_prob=0.0)).train()
    cfg = m.cfg
    B, T = 4, 10
    codes = torch.randint(0, cfg.codebook_size, (B, T, cfg.num_levels))
    tok_in = torch.cat([torch.full((B, 1, cfg.num_levels), cfg.bos_id), codes], dim=1)
    tgt = torch.cat([codes, torch.full((B, 1, cfg.num_levels), cfg.end_id)], dim=1)
    lengths, text = torch.full((B,), T), torch.randn(B, cfg.text_dim)
    opt = torch.optim.Adam(m.parameters(), 3e-3)
    losses = []
    for _ in range(15):
        loss, _ = m.loss(text, tok_in, tgt, lengths)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.8 * losses[0]


@pytest.mark.parametrize("name", NAMES)
def test_presets_build_and_take_a_training_step(name):
    torch.manual_seed(0)
    m = RQHCTransformer(get_preset(name).transformer_config()).train()
    cfg = m.cfg
    B, S = 1, 4
    tok = _tokens(cfg, B, S)
    tgt = torch.randint(0, cfg.codebook_size + 1, (B, S, cfg.num_levels))
    opt = torch.optim.SGD(m.parameters(), 1e-3)
    loss, _ = m.loss(torch.randn(B, cfg.text_dim), tok, tgt, torch.tensor([S - 1]))
    before = m.head.weight.detach().clone()
    opt.zero_grad()
    loss.backward()
    opt.step()
    assert torch.isfinite(loss) and not torch.equal(before, m.head.weight)


def test_the_control_adapter_adds_nothing_where_the_control_is_absent():
    """Rows (and steps) without control give the model without adapters' logits exactly, even with trained
    (non-zero) adapters; controlled steps change, and only from their own step on."""
    base = _model()
    m = RQHCTransformer(get_preset("tiny").transformer_config(adapter_dim=8)).eval()
    m.load_state_dict(base.state_dict(), strict=False)
    g = torch.Generator().manual_seed(3)
    for p in m.adapters.parameters():
        p.data = torch.randn(p.shape, generator=g)  # as if trained: the up projection no longer zero
    cfg = m.cfg
    B, S = 3, 7
    text, tok = torch.randn(B, cfg.text_dim, generator=g), _tokens(cfg, B, S)
    control = torch.randn(B, S, cfg.control_dim, generator=g)
    control[..., 0] = 1.0
    control[1] = 0.0          # a free character in the batch
    control[2, :4] = 0.0      # steered from step 4 on
    with torch.no_grad():
        assert torch.equal(m(text, tok), base(text, tok))                       # no control given at all
        got, want = m(text, tok, control), base(text, tok, control)
    assert torch.equal(got[1], want[1]) and torch.equal(got[2, :4], want[2, :4])
    assert (got[0] - want[0]).abs().amax() > 1e-3 and (got[2, 4:] - want[2, 4:]).abs().amax() > 1e-3


def test_the_control_adapter_starts_as_nothing_and_needs_control():
    m = _model(adapter_dim=8)
    assert all(torch.count_nonzero(a.up.weight) == 0 for a in m.adapters)
    with pytest.raises(ValueError, match="needs a model with control"):
        RQHCTransformer(get_preset("tiny").transformer_config(adapter_dim=8, control_horizon=0))
