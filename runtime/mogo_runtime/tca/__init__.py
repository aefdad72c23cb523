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
sentence, strip_subject, caption_verbs; offline.py, OfflineAligner (each clause -> its nearest training caption).
The generator imports this package on the first `align=True`. Rewriting with an external chat model is the
separate package `mogo_rewriter` (not shipped to devices).
"""
from .base import AlignedPrompt, Aligner, apply_alignment
from .index import INDEX_FORMAT, INDEX_VERSION, CaptionIndex, load_bundle_index, quantize_rows
from .offline import DEFAULTS, OfflineAligner
from .wording import WordingNormalizer, caption_verbs, sentence, strip_subject

__all__ = ["AlignedPrompt", "Aligner", "apply_alignment", "INDEX_FORMAT", "INDEX_VERSION", "CaptionIndex",
           "load_bundle_index", "quantize_rows", "DEFAULTS", "OfflineAligner", "WordingNormalizer", "caption_verbs",
           "sentence", "strip_subject"]
