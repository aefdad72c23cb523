"""Random tiny models (parity needs no training) exported to a bundle with every variant (fp32, int8, portable,
int8_ort, portable_ort), once per test process: test_export.py and test_portable.py share it.

(Not a tests/export/conftest.py: that would shadow tests/conftest.py for `from conftest import ROOT`.)
"""
import numpy as np
import torch

from mogo_export.checkpoint import save_checkpoint
from mogo_export.export.bundle import export_bundle
from mogo_export.models import transformer as T
from mogo_export.models import vq as V
from mogo_export.presets import get_preset

_BUILT: dict = {}


def random_tiny_bundle(tmp_path_factory) -> dict:
    """-> {"vq", "tr", "mean", "std", "bundle", "root"}: the models, their bundle and the checkpoint root."""
    if not _BUILT:
        root = tmp_path_factory.mktemp("export")
        torch.manual_seed(0)
        vc = get_preset("tiny").vq_config()
        vq = V.MoSAVQ(vc).eval()
        tc = get_preset("tiny").transformer_config(num_levels=vc.num_levels, codebook_size=vc.codebook_size,
                                                   text_dim=64)
        tr = T.RQHCTransformer(tc).eval()
        rng = np.random.default_rng(0)
        mean, std = rng.normal(size=263).astype(np.float32), rng.uniform(0.5, 2, size=263).astype(np.float32)
        meta = {"mean": mean.tolist(), "std": std.tolist(), "fps": 20.0, "preset": "tiny", "skeleton": "humanml3d"}
        save_checkpoint(root / "ck" / "vq.pt", "vq", vc, vq, {"step": 0, "done": True}, meta)
        save_checkpoint(root / "ck" / "transformer.pt", "transformer", tc, tr, {"step": 0, "done": True},
                        {"text_encoder": "tiny-random-bert", "max_tokens": 24})
        bundle = export_bundle(root / "ck", root / "bundle", log=lambda *a: None)
        _BUILT.update(vq=vq, tr=tr, mean=mean, std=std, bundle=bundle, root=root)
    return _BUILT
