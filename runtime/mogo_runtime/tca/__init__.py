"""Text condition alignment (TCA, the paper's section 2.3): prompts rewritten into the training captions' style.

The model conditions best on prompts like its captions ("a person jumps in place twice."), not on "yo make the
dude do a lil hop". The paper rewrites prompts with a large language model; a device has none, so the default is
offline, from the bundle (docs/tca.md):

    from mogo_runtime.tca import OfflineAligner
    aligner = OfflineAligner(bundle, text_session)          # bundle has captions.npz (manifest section "tca")
    aligner.align("guy starts jogging real quick, then sits").text   # 'a person jogs ... and then sits down.'

Modules: base.py, the interface the generator uses (Aligner, AlignedPrompt, apply_alignment); index.py, CaptionIndex
and the captions.npz format ("mogo-caption-index") shared with the exporter; lexicon.py, the wording normaliser's
words and patterns (data); wording.py, WordingNormalizer (prompt -> caption-style clauses) and the caption helpers
sentence, strip_subject, caption_verbs; offline.py, OfflineAligner (each clause -> its nearest training caption);
rewriter.py, ChatRewriter (an external chat model, falling back to the offline aligner; opt-in). Names load on
first use (PEP 562): `import mogo_runtime.tca` reads no submodule, `Aligner` reads base.py only, and only code
asking for `ChatRewriter` reads the rewriter.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

_HOME = {"AlignedPrompt": "base", "Aligner": "base", "apply_alignment": "base", "CaptionIndex": "index",
         "INDEX_FORMAT": "index", "INDEX_VERSION": "index", "load_bundle_index": "index", "quantize_rows": "index",
         "WordingNormalizer": "wording", "caption_verbs": "wording", "sentence": "wording", "strip_subject": "wording",
         "DEFAULTS": "offline", "OfflineAligner": "offline", "ChatRewriter": "rewriter", "RewriterError": "rewriter"}
__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value          # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))


if TYPE_CHECKING:
    from .base import AlignedPrompt, Aligner, apply_alignment
    from .index import INDEX_FORMAT, INDEX_VERSION, CaptionIndex, load_bundle_index, quantize_rows
    from .offline import DEFAULTS, OfflineAligner
    from .rewriter import ChatRewriter, RewriterError
    from .wording import WordingNormalizer, caption_verbs, sentence, strip_subject
