"""Guidance distillation (mogo_export/distill.py): the measure is zero where there is nothing to learn, a few steps
bring the student's conditional row toward the teacher's guided distribution (toward the control too, where a
sample has one) while its unconditional row stays,
and the distilled tiny model (train_all runs the phase) ships a bundle whose default sampling runs one row."""
import copy

import numpy as np
import torch

from mogo_export.checkpoint import build_from_checkpoint, read_checkpoint
from mogo_export.distill import TEACHER, guided_kl, is_distilled
from mogo_export.distributed import native_bf16
from mogo_export.examples import caption_table, clip_examples, load_token_data, pad_examples
from mogo_export.models import transformer as tmodel
from mogo_export.presets import get_preset
from mogo_runtime import Bundle, MotionGenerator


def _batch(cfg, seed=0, batch=6, steps=9):
    g = torch.Generator().manual_seed(seed)
    text = torch.randn(batch, cfg.text_dim, generator=g)
    tokens = torch.randint(0, cfg.codebook_size, (batch, steps, cfg.num_levels), generator=g)
    tokens[:, 0] = cfg.bos_id
    lengths = torch.randint(2, steps, (batch,), generator=g)
    return text, tokens, lengths


def _models(tiny_checkpoints):
    student, cfg, _ = build_from_checkpoint(tiny_checkpoints / "transformer.pt", "transformer",
                                            tmodel.TransformerConfig, tmodel.RQHCTransformer)
    teacher, _, _ = build_from_checkpoint(tiny_checkpoints / TEACHER, "transformer", tmodel.TransformerConfig,
                                          tmodel.RQHCTransformer)
    return student.eval(), teacher.eval(), cfg


def test_nothing_to_learn_measures_zero(tiny_checkpoints):
    _, teacher, cfg = _models(tiny_checkpoints)
    text, tokens, lengths = _batch(cfg)
    with torch.no_grad():
        same = guided_kl(copy.deepcopy(teacher), teacher, text, tokens, lengths, guidance=1.0, uncond_weight=1.0)
        guided = guided_kl(copy.deepcopy(teacher), teacher, text, tokens, lengths, guidance=2.0, uncond_weight=1.0)
    assert abs(float(same)) < 1e-6 and float(guided) > 1e-4


def _control(cfg, tokens, steered):
    """A control for each sample of a batch: random wanted poses where `steered`, none (all zeros) elsewhere."""
    B, S, _ = tokens.shape
    control = torch.randn(B, S, cfg.control_dim, generator=torch.Generator().manual_seed(1))
    control[..., 0] = 1.0                                  # present
    return control * torch.as_tensor(steered, dtype=control.dtype)[:, None, None]


def test_control_guidance_guides_only_the_samples_with_control(tiny_checkpoints):
    """Guidance toward the control changes the target only where a sample has one: none anywhere measures what
    text guidance alone does, and the teacher is its own target at both guidances 1, with control or not."""
    _, teacher, cfg = _models(tiny_checkpoints)
    assert cfg.control_dim
    text, tokens, lengths = _batch(cfg)
    none = _control(cfg, tokens, [False] * len(tokens))
    one = _control(cfg, tokens, [True] + [False] * (len(tokens) - 1))
    with torch.no_grad():
        def kl(control, g, gc):
            return float(guided_kl(copy.deepcopy(teacher), teacher, text, tokens, lengths, g, 1.0, control, gc))
        assert abs(kl(one, 1.0, 1.0)) < 1e-6 and abs(kl(none, 1.0, 3.0)) < 1e-6
        assert abs(kl(none, 2.0, 3.0) - kl(None, 2.0, 1.0)) < 1e-6
        assert kl(one, 1.0, 3.0) > 1e-4


def test_the_distilled_tiny_model_gives_more_of_the_guided_distribution(tiny_checkpoints):
    """train_all distilled the tiny model (its preset's few steps, on the training split): on the validation split's
    clips, its conditional row is closer to the teacher's guided distribution than the teacher's own conditional row
    is."""
    assert is_distilled(tiny_checkpoints) and (tiny_checkpoints / TEACHER).exists()
    plan = get_preset("tiny").distill
    payload = read_checkpoint(tiny_checkpoints / "transformer.pt", "transformer")
    assert payload["meta"]["distilled"]["guidance"] == plan.guidance
    assert payload["meta"]["distilled"]["steps"] == plan.steps
    student, teacher, cfg = _models(tiny_checkpoints)
    data = tiny_checkpoints.parent / "data"
    table, emb, _ = caption_table(data, tiny_checkpoints, payload["meta"]["text_encoder"], write=False)
    downsample = read_checkpoint(tiny_checkpoints / "vq.pt", "vq")["config"]["downsample"]
    d = load_token_data(data, tiny_checkpoints / "tokens.npz", table, emb, cfg, downsample)
    assert payload["meta"]["distilled"]["control_guidance"] == plan.control_guidance != 1.0
    rng = np.random.default_rng(0)
    measures = {"without control": ([], []), "with their own control": ([], [])}
    with torch.no_grad():
        for _ in range(4):
            text, tokens, _, lengths, control = pad_examples(clip_examples(d.val_seqs, d.val_caps, emb, rng, 8, cfg,
                                                                           controls=d.val_controls), cfg)
            for (before, after), c in zip(measures.values(), (None, control)):
                for model, out in ((teacher, before), (student, after)):
                    out.append(float(guided_kl(model, teacher, text, tokens, lengths, plan.guidance, 0.0, c,
                                               plan.control_guidance)))
    for name, (before, after) in measures.items():
        print(f"validation clips {name}, KL(guided || conditional row): teacher {np.mean(before):.4f}, "
              f"distilled {np.mean(after):.4f}")
        assert np.mean(after) < 0.8 * np.mean(before), name


def test_a_distilled_bundle_samples_with_one_row(tiny_bundle):
    bundle = Bundle.load(tiny_bundle)
    defaults = bundle.manifest.sampling_defaults
    assert defaults.guidance == 1.0 and defaults.top_p == 0.8
    gen = MotionGenerator(tiny_bundle, variant="fp32")
    motion = gen.generate("a person walks forward", seed=1)               # the defaults: one row per token
    assert len(motion.tokens) > 0


def test_bf16_only_where_the_device_computes_it_natively():
    cpu = torch.device("cpu")
    assert native_bf16(cpu, "flags\t\t: fpu sse2 avx2 avx512f avx512_bf16 vnni")
    assert native_bf16(cpu, "flags\t\t: fpu avx2 amx_bf16 amx_tile")
    assert native_bf16(cpu, "Features\t: fp asimd evtstrm bf16 i8mm")                  # ARM
    assert not native_bf16(cpu, "flags\t\t: fpu sse2 avx2 avx512f avx512bw avx512_vnni")   # emulated: slower
    assert not native_bf16(torch.device("meta"), "flags: avx512_bf16")


def test_the_guided_kl_in_bf16_autocast_is_float32_and_close(tiny_checkpoints):
    """Under autocast the products run in bf16; the distributions and the loss stay float32 and near fp32's."""
    student, teacher, cfg = _models(tiny_checkpoints)
    text, tokens, lengths = _batch(cfg)
    with torch.no_grad():
        fp32 = guided_kl(student, teacher, text, tokens, lengths, guidance=2.0, uncond_weight=1.0)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            bf16 = guided_kl(student, teacher, text, tokens, lengths, guidance=2.0, uncond_weight=1.0)
    print(f"guided KL fp32 {float(fp32):.5f}, bf16 autocast {float(bf16):.5f}")
    assert bf16.dtype == torch.float32 and float(fp32) > 0
    assert abs(float(bf16) - float(fp32)) < 0.1 * float(fp32)
