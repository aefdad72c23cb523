"""MoSA-VQ: eq. 1-5 quantization, lookup identity, EMA/dead-code upkeep, quantize dropout, causal decoder."""
import pytest
import torch

from mogo_export.models.vq import MoSAVQ, MotionDecoder, ResidualQuantizer, VQConfig
from mogo_export.presets import NAMES, get_preset


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _model(seed=0, **kw):
    torch.manual_seed(seed)
    return MoSAVQ(get_preset("tiny").vq_config(**kw))


def _randomise_scaling(q: ResidualQuantizer):
    # away from the init (s = 1, b = 0) so that a wrong formula cannot hide behind identity values
    with torch.no_grad():
        q.scale.copy_(torch.rand_like(q.scale) + 0.5)
        q.bias.copy_(torch.randn_like(q.bias))


@pytest.mark.parametrize("downsample", [1, 2, 4])
def test_shapes_and_loss_terms(downsample):
    m = _model(downsample=downsample)
    cfg = m.cfg
    x = torch.randn(3, 16, cfg.input_dim)
    recon, terms = m(x)
    assert recon.shape == x.shape
    for k in ("loss", "recon", "commit", "reg", "vel"):
        assert terms[k].shape == () and torch.isfinite(terms[k])
    assert terms["perplexity"].shape == terms["usage"].shape == (cfg.num_levels,)
    m.eval()
    idx = m.encode(x)
    assert idx.shape == (3, 16 // downsample, cfg.num_levels) and idx.dtype == torch.int64
    assert 0 <= idx.min() and idx.max() < cfg.codebook_size
    assert m.decode_indices(idx).shape == x.shape


def test_quantizer_follows_eq_1_to_5():
    """Indices are the nearest codes of ||s^l|| r^l + b^l; the latent is sum_l (C[idx] - b^l) / ||s^l||."""
    m = _model(num_levels=3)
    q = m.quantizer.eval()
    _randomise_scaling(q)
    L, K = m.cfg.num_levels, m.cfg.codebook_size
    z = torch.randn(2, 5, m.cfg.code_dim)
    out = q(z)
    r, total = z.clone(), torch.zeros_like(z)
    for l in range(L):
        gain = q.scale[l].norm()  # ||s^l||: the L2 norm of the vector s^l, one number per level
        r_scaled = gain * r + q.bias[l]  # eq. 1
        book = q.codebook[l * K:(l + 1) * K]
        idx = torch.cdist(r_scaled.reshape(-1, r.shape[-1]), book).argmin(-1).reshape(2, 5)  # eq. 2
        assert torch.equal(idx, out.indices[..., l])
        b = (book[idx] - q.bias[l]) / gain  # eq. 3
        r, total = r - b, total + b  # eq. 4, 5
    torch.testing.assert_close(out.quantized, total, atol=1e-5, rtol=1e-5)
    # eq. 6: commitment and the scale/bias regulariser
    reg = ((q.scale - 1) ** 2).sum() + (q.bias ** 2).sum()
    torch.testing.assert_close(out.reg, reg)


def test_lookup_of_encoded_indices_is_the_quantized_latent():
    m = _model(num_levels=3).eval()
    _randomise_scaling(m.quantizer)
    x = torch.randn(2, 12, m.cfg.input_dim)
    z = m.encoder(x)
    assert torch.equal(m.quantizer.lookup(m.encode(x)), m.quantizer(z).quantized)
    # and the decoded indices are exactly the model's eval reconstruction
    assert torch.equal(m.decode_indices(m.encode(x)), m(x)[0])


def test_plain_rvq_without_learnable_scaling():
    m = _model(learnable_scaling=False, num_levels=2).eval()
    q = m.quantizer
    assert not hasattr(q, "scale") and all("scale" not in n and "bias" not in n.split(".")[-1]
                                           for n, _ in q.named_parameters())
    z = torch.randn(2, 4, m.cfg.code_dim)
    out = q(z)
    K = m.cfg.codebook_size
    expect = q.codebook[out.indices[..., 0]] + q.codebook[K + out.indices[..., 1]]
    torch.testing.assert_close(out.quantized, expect)
    assert out.reg == 0


def test_codebook_is_one_2d_table_and_gets_no_gradient():
    m = _model()
    cfg = m.cfg
    assert m.quantizer.codebook.shape == (cfg.num_levels * cfg.codebook_size, cfg.code_dim)
    assert "codebook" not in dict(m.named_parameters())
    x = torch.randn(2, 8, cfg.input_dim)
    _, terms = m(x)
    terms["loss"].backward()
    # straight-through to the encoder; s and b learn through the inverse transform of eq. 3
    assert m.encoder.net[0].weight.grad.abs().sum() > 0
    assert m.quantizer.scale.grad.abs().sum() > 0 and m.quantizer.bias.grad.abs().sum() > 0


def test_first_training_batch_seeds_codebooks_from_scaled_residuals():
    m = _model(quantize_dropout_prob=0.0, ema_decay=1.0)  # decay 1 freezes the codebook right after seeding
    K, d = m.cfg.codebook_size, m.cfg.code_dim
    x = torch.randn(4, 16, m.cfg.input_dim)
    z = m.encoder(x).detach().reshape(-1, d)
    assert not m.quantizer.initted.any()
    with torch.no_grad():
        m(x)
    q = m.quantizer
    assert q.initted.all()
    # every level-0 code is one of the scaled encoder outputs (s = 1, b = 0 at init: gain sqrt(d))
    scaled = z * q.scale[0].norm()
    assert torch.cdist(q.codebook[:K], scaled).min(dim=1).values.max() < 1e-3


def _one_level(**kw):
    torch.manual_seed(0)
    cfg = get_preset("tiny").vq_config(num_levels=1, codebook_size=8, code_dim=4, quantize_dropout_prob=0.0,
                                       learnable_scaling=False, ema_decay=0.5, **kw)
    q = ResidualQuantizer(cfg).train()
    q.initted.fill_(True)
    with torch.no_grad():
        q.codebook.copy_(torch.arange(8.0).unsqueeze(1).repeat(1, 4) * 100)  # codes far apart
        q.ema_sum.copy_(q.codebook)
        q.ema_count.fill_(1.0)
    return q


POINT = torch.tensor([1.0, 2.0, 3.0, 4.0])


def test_ema_moves_a_code_towards_its_members():
    q = _one_level(dead_code_threshold=0.1)
    out = q(torch.zeros(1, 6, 4) + POINT)  # six vectors, all nearest to code 0
    assert (out.indices == 0).all()
    # count 0.5*1 + 0.5*6 = 3.5, sum 0.5*0 + 0.5*6*POINT: the code moves to 3/3.5 of the way
    torch.testing.assert_close(q.codebook[0], POINT * 3 / 3.5, atol=1e-4, rtol=0)
    # codes without members keep their place while their count (0.5) is above the floor 0.1 * 7/8
    torch.testing.assert_close(q.codebook[1:], torch.arange(1.0, 8).unsqueeze(1).repeat(1, 4) * 100, rtol=1e-4, atol=0)


def test_dead_codes_restart_on_current_residuals():
    q = _one_level(dead_code_threshold=0.9)  # floor 0.9 * 7/8 = 0.79 > 0.5: codes 1..7 are dead
    q(torch.zeros(1, 6, 4) + POINT)
    torch.testing.assert_close(q.codebook[1:], POINT.expand(7, 4))
    torch.testing.assert_close(q.ema_count[1:], torch.full((7,), 0.9 * 7 / 8))
    torch.testing.assert_close(q.codebook[0], POINT * 3 / 3.5, atol=1e-4, rtol=0)


def test_encode_has_no_side_effects_even_in_training_mode():
    m = _model().train()
    x = torch.randn(2, 8, m.cfg.input_dim)
    before = {k: v.clone() for k, v in m.quantizer.state_dict().items()}
    m.encode(x)
    for k, v in m.quantizer.state_dict().items():
        assert torch.equal(v, before[k]), k


def test_quantize_dropout_drops_a_random_suffix_of_levels():
    m = _model(num_levels=4, quantize_dropout_prob=1.0)
    x = torch.randn(2, 8, m.cfg.input_dim)
    seen = set()
    for _ in range(30):
        out = m.quantizer(m.encoder(x))
        active = (out.indices[0, 0] >= 0).sum().item()
        assert 1 <= active <= 3
        assert (out.indices[..., :active] >= 0).all() and (out.indices[..., active:] == -1).all()
        assert (out.perplexity[active:] == 0).all()
        seen.add(active)
    assert seen == {1, 2, 3}
    m.eval()  # never in eval
    assert (m.quantizer(m.encoder(x)).indices >= 0).all()


@pytest.mark.parametrize("downsample,depth", [(1, 2), (2, 2), (4, 2), (4, 3)])
def test_decoder_is_causal_with_the_stated_receptive_field(downsample, depth):
    torch.manual_seed(0)
    cfg = get_preset("tiny").vq_config(downsample=downsample, depth=depth)
    # float64: the farthest token's effect passes ~15 random convs and ReLUs and can be ~1e-8; it must not
    # drown in rounding, and any difference at all proves a dependency (untouched inputs give equal outputs)
    dec = MotionDecoder(cfg).double().eval()
    R = dec.receptive_field
    T = R + 12
    z = torch.randn(1, T, cfg.code_dim, dtype=torch.float64)
    base = dec(z)
    for i in (3, 7):
        z2 = z.clone()
        z2[0, i] += 1.0
        diff = (dec(z2) - base).abs().amax(dim=-1)[0]  # (T * downsample,)
        frames_of = lambda tok: slice(tok * downsample, (tok + 1) * downsample)
        assert diff[: i * downsample].max() == 0, "a frame changed before its token"
        assert diff[frames_of(i)].max() > 1e-4
        # the oldest token a frame can still see is R back; one more and nothing changes
        assert diff[frames_of(i + R)].max() > 0, "receptive field is not tight"
        assert diff[(i + R + 1) * downsample:].max() == 0, "receptive field is too small"


def test_velocity_term_is_optional():
    x = torch.randn(2, 8, 263)
    assert _model()(x)[1]["vel"] == 0
    _, terms = _model(vel_loss=0.5)(x)
    assert terms["vel"] > 0
    torch.testing.assert_close(terms["loss"], terms["recon"] + 0.02 * terms["commit"] + 1e-4 * terms["reg"]
                               + 0.5 * terms["vel"], rtol=1e-5, atol=1e-6)


def _feature_grads(x, recon, **cfg):
    """|d loss / d recon| per feature, for a fixed reconstruction scored by a model built with `cfg`."""
    m = _model(quantize_dropout_prob=0.0, **cfg)
    recon = recon.clone().requires_grad_(True)
    m.decoder.forward = lambda z: recon  # score this reconstruction, whatever the latent
    m(x)[1]["loss"].backward()
    return recon.grad.abs().mean(dim=(0, 1))  # (D,)


def test_the_squared_term_pulls_hardest_where_the_error_is_largest():
    torch.manual_seed(0)
    x = torch.randn(1, 8, 263)
    err = torch.zeros_like(x)
    err[..., 10] = 10.0  # a feature far off (a raised arm the model missed)
    err[..., 11] = 0.1   # a feature slightly off
    g = _feature_grads(x, x + err)
    torch.testing.assert_close(g[10], g[11])  # L1: every error pulls alike
    g = _feature_grads(x, x + err, mse_loss=0.1)
    assert g[10] > 2 * g[11], "the squared term should pull the far feature harder"


def test_a_few_optimiser_steps_lower_the_loss():
    torch.manual_seed(0)
    m = MoSAVQ(get_preset("tiny").vq_config(quantize_dropout_prob=0.0))
    t = torch.linspace(0, 6.28, 32)
    phase = torch.arange(263).unsqueeze(1) * 0.1
    x = torch.stack([torch.sin(t * (k + 1) / 3 + phase).T for k in range(4)])  # (4, 32, 263) smooth clips
    opt = torch.optim.Adam(m.parameters(), 3e-3)
    losses = []
    for _ in range(15):
        _, terms = m(x)
        opt.zero_grad()
        terms["loss"].backward()
        opt.step()
        losses.append(terms["recon"].item())
    assert sum(losses[-3:]) / 3 < 0.8 * sum(losses[:3]) / 3


@pytest.mark.parametrize("name", NAMES)
def test_presets_build_and_take_a_training_step(name):
    torch.manual_seed(0)
    m = MoSAVQ(get_preset(name).vq_config())
    assert m.param_count() == sum(p.numel() for p in m.parameters())
    cfg = m.cfg
    x = torch.randn(1, 4 * cfg.downsample, cfg.input_dim)
    opt = torch.optim.AdamW(m.parameters(), 1e-4)
    before = m.decoder.net[0].weight.detach().clone()
    _, terms = m(x)
    opt.zero_grad()
    terms["loss"].backward()
    opt.step()
    assert torch.isfinite(terms["loss"]) and not torch.equal(before, m.decoder.net[0].weight)
    if name == "paper":
        assert (cfg.num_levels, cfg.codebook_size, cfg.code_dim, cfg.width, cfg.downsample) == (6, 8192, 128, 512, 1)


def test_length_must_be_a_multiple_of_the_downsample():
    m = _model(downsample=4)
    with pytest.raises(AssertionError):
        m(torch.randn(1, 10, 263))
    assert isinstance(m.cfg, VQConfig)


def test_the_root_weight_pulls_the_root_channels_harder_and_only_them():
    torch.manual_seed(0)
    x = torch.randn(1, 8, 263)
    err = torch.full_like(x, 0.5)   # every feature off by the same amount
    g1 = _feature_grads(x, x + err)
    g5 = _feature_grads(x, x + err, root_loss=5.0)
    torch.testing.assert_close(g1[:4], g1[4:8])       # weight 1: the root is 4 channels among 263
    torch.testing.assert_close(g5[:4], 5 * g1[:4])    # its errors count 5 times
    torch.testing.assert_close(g5[4:], g1[4:])
    # the squared term sees the weighted error, as if the root's Std were 5 times smaller: 5 x 5 on top of L1
    s1 = _feature_grads(x, x + err, mse_loss=0.1)
    s5 = _feature_grads(x, x + err, mse_loss=0.1, root_loss=5.0)
    torch.testing.assert_close(s5[:4] - g5[:4], 25 * (s1[:4] - g1[:4]))
    torch.testing.assert_close(s5[4:], s1[4:])
