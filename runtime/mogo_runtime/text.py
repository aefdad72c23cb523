"""Text prompts to embeddings with onnxruntime: the tokenizer settings, the text encoder session, and the
onnxruntime session options every graph of the runtime is opened with.

The tokenizer settings live here, once: the torch side (`mogo_export.models.text_encoder`) imports
`TokenizerSettings`, `configure_tokenizer` and `tokenize` from this module, the exporter writes a
`tokenizer.json` with them applied (plus `max_length` in the graph's metadata), and `TextEncoderSession`
reads them back from that file. So training, export and runtime cut and pad prompts the same way.

    from mogo_runtime.text import TextEncoderSession
    enc = TextEncoderSession("bundle/text_encoder.onnx", "bundle/tokenizer.json", threads=1)
    emb = enc.encode(["a person walks forward"])    # (1, 384) float32, L2-normalised
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tokenizers import Tokenizer



@dataclass(frozen=True)
class TokenizerSettings:
    max_length: int = 256      # tokens incl. [CLS]/[SEP]; sentence-transformers' max_seq_length for MiniLM
    pad_token: str = "[PAD]"   # padded to the longest prompt in the batch, on the right

    @classmethod
    def from_tokenizer(cls, tok: Tokenizer, source: str = "tokenizer") -> "TokenizerSettings":
        """Read back the settings an exported tokenizer.json carries; refuse one that was never configured."""
        trunc, pad = tok.truncation, tok.padding
        if trunc is None:
            raise ValueError(f"{source}: no truncation configured; long prompts would exceed the encoder's "
                             f"positions. Re-export the text encoder (it writes truncation into tokenizer.json)")
        if pad is None or pad.get("length") is not None:
            # a fixed length (the shipped MiniLM file pads to 128) wastes compute; none breaks batching
            raise ValueError(f"{source}: padding must be 'longest in batch', found {pad!r}; "
                             f"re-export the text encoder")
        if trunc.get("direction", "right") != "right" or pad.get("direction", "right") != "right":
            raise ValueError(f"{source}: truncation and padding must both be on the right, "
                             f"found {trunc!r} / {pad!r}")
        return cls(max_length=int(trunc["max_length"]), pad_token=str(pad["pad_token"]))


def configure_tokenizer(tok: Tokenizer, settings: TokenizerSettings) -> Tokenizer:
    """Apply `settings` to `tok` in place (and return it); the one place truncation and padding are set."""
    pad_id = tok.token_to_id(settings.pad_token)
    if pad_id is None:
        raise ValueError(f"pad token {settings.pad_token!r} is not in the tokenizer's vocabulary")
    tok.enable_truncation(max_length=settings.max_length, strategy="longest_first", direction="right")
    tok.enable_padding(direction="right", pad_id=pad_id, pad_type_id=0, pad_token=settings.pad_token, length=None)
    return tok


def check_texts(texts: list[str]) -> list[str]:
    """Reject what would silently embed to nonsense: a bare string, an empty list, blank prompts."""
    if isinstance(texts, str):
        raise TypeError("encode() takes a list of prompts, got a single str; wrap it: encode([text])")
    texts = list(texts)
    if not texts:
        raise ValueError("encode() got an empty list of prompts")
    for i, t in enumerate(texts):
        if not isinstance(t, str):
            raise TypeError(f"prompt {i} is a {type(t).__name__}, expected str")
        if not t.strip():
            raise ValueError(f"prompt {i} is empty or whitespace only ({t!r}); describe a motion, "
                             f"e.g. 'a person walks forward'")
    return texts


def tokenize(tok: Tokenizer, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Prompts -> (input_ids, attention_mask), both (N, S) int64, S = longest prompt (<= max_length)."""
    encs = tok.encode_batch(check_texts(texts))
    ids = np.array([e.ids for e in encs], dtype=np.int64)              # (N, S)
    mask = np.array([e.attention_mask for e in encs], dtype=np.int64)  # (N, S) 1 = token, 0 = padding
    return ids, mask


def session_options(threads: int):
    """Options for sitting inside a host application: few threads, one graph at a time."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    if threads > 1:
        # spinning workers fight the host's own threads for the cores: 2 spinning threads measured 2-3x slower
        # than 1 thread on a busy 2-core machine, and 52% slower than 2 threads without spinning
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts


class TextEncoderSession:
    """An exported text encoder (`text_encoder.onnx` + `tokenizer.json`) on onnxruntime, CPU by default."""

    def __init__(self, onnx_path: str | Path, tokenizer_path: str | Path, threads: int = 1,
                 providers: list[str] | None = None):
        import onnxruntime as ort  # imported here so `tokenize` works without onnxruntime

        self.tokenizer = Tokenizer.from_file(str(tokenizer_path))
        self.settings = TokenizerSettings.from_tokenizer(self.tokenizer, source=str(tokenizer_path))

        self.session = ort.InferenceSession(str(onnx_path), session_options(threads),
                                            providers=providers or ["CPUExecutionProvider"])

        names = {i.name for i in self.session.get_inputs()}
        if names != {"input_ids", "attention_mask"}:
            raise ValueError(f"{onnx_path}: expected inputs input_ids, attention_mask; found {sorted(names)}")
        self.output_name = self.session.get_outputs()[0].name
        meta = self.session.get_modelmeta().custom_metadata_map
        for key in ("dim", "max_length", "encoder"):
            if key not in meta:
                raise ValueError(f"{onnx_path}: metadata_props lacks {key!r}; was it written by export_text_encoder?")
        self.dim = int(meta["dim"])
        self.name = meta["encoder"]
        if int(meta["max_length"]) != self.settings.max_length:
            # torch embedded captions cut at meta's length; a different cut here would shift long prompts
            raise ValueError(f"{tokenizer_path} truncates at {self.settings.max_length} tokens but {onnx_path} "
                             f"was exported for max_length={meta['max_length']}")

    def encode(self, texts: list[str], batch_size: int = 64) -> np.ndarray:
        """Prompts -> (N, dim) float32 embeddings (L2-normalised when the graph's metadata says so)."""
        texts = check_texts(texts)
        out = []
        for i in range(0, len(texts), batch_size):
            ids, mask = tokenize(self.tokenizer, texts[i:i + batch_size])
            (emb,) = self.session.run([self.output_name], {"input_ids": ids, "attention_mask": mask})
            out.append(emb)
        emb = np.concatenate(out).astype(np.float32, copy=False)   # (N, dim)
        if emb.shape[1] != self.dim:
            raise ValueError(f"text encoder returned width {emb.shape[1]}, metadata says dim={self.dim}")
        return emb
