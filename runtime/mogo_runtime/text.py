"""Text prompts to embeddings with onnxruntime: the tokenizer settings, the text encoder session, and the
onnxruntime session options every graph of the runtime is opened with.

The tokenizer settings live here, once: the torch side (`mogo_export.models.text_encoder`) imports
`TokenizerSettings`, `configure_tokenizer` and `tokenize` from this module, the exporter writes a
`tokenizer.json` with them applied (plus `max_length` in the graph's metadata), and `TextEncoderSession`
reads them back from that file. So training, export and runtime cut and pad prompts the same way. The torch side
tokenizes with HuggingFace's `tokenizers` library, the runtime with its own reading of the same file
(mogo_runtime.tokenizer: same ids, no dependency); these functions take either.

    from mogo_runtime.text import TextEncoderSession
    enc = TextEncoderSession("bundle/text_encoder.onnx", "bundle/tokenizer.json", threads=1)
    emb = enc.encode(["a person walks forward"])    # (1, 384) float32, L2-normalised
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .checks import as_int, shown
from .tokenizer import PARTS as TOKENIZER_PARTS  # noqa: F401 - read by the JavaScript tests (make_reference.py)
from .tokenizer import Tokenizer

# The encoder reads a prompt's first max_length tokens (a few hundred words) and drops the rest, but the tokenizer
# and the aligner work on all of it first: a 10 MB prompt took 36 s and 5 GB before being cut (CJK text, one token
# a character). 10,000 characters is many times what any bundle reads.
MAX_PROMPT_CHARS = 10_000
MAX_THREADS = 64   # onnxruntime segfaults or hangs on absurd thread counts; no CPU this runs on has more cores


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
        multiple = pad.get("pad_to_multiple_of") if pad is not None else None
        if multiple is not None and not (isinstance(multiple, int) and 1 <= multiple <= trunc["max_length"]):
            # rounding up past max_length would pad every batch past what the encoder reads
            raise ValueError(f"{source}: padding.pad_to_multiple_of must be in [1, {trunc['max_length']}], got "
                             f"{shown(multiple)}")
        if pad is None or pad.get("length") is not None:
            # a fixed length (the shipped MiniLM file pads to 128) wastes compute; none breaks batching
            raise ValueError(f"{source}: padding must be 'longest in batch', found {shown(pad, 200)}; "
                             f"re-export the text encoder")
        if trunc.get("direction", "right") != "right" or pad.get("direction", "right") != "right":
            raise ValueError(f"{source}: truncation and padding must both be on the right, "
                             f"found {shown(trunc, 200)} / {shown(pad, 200)}")
        return cls(max_length=int(trunc["max_length"]), pad_token=str(pad["pad_token"]))


def configure_tokenizer(tok: Tokenizer, settings: TokenizerSettings) -> Tokenizer:
    """Apply `settings` to `tok` in place (and return it); the one place truncation and padding are set."""
    pad_id = tok.token_to_id(settings.pad_token)
    if pad_id is None:
        raise ValueError(f"pad token {shown(settings.pad_token)} is not in the tokenizer's vocabulary")
    tok.enable_truncation(max_length=settings.max_length, strategy="longest_first", direction="right")
    tok.enable_padding(direction="right", pad_id=pad_id, pad_type_id=0, pad_token=settings.pad_token, length=None)
    return tok


def load_tokenizer(data: bytes, name: str) -> Tokenizer:
    """A tokenizer.json's bytes -> the runtime's Tokenizer (mogo_runtime.tokenizer), with its settings checked
    (TokenizerSettings.from_tokenizer); a file that is not one, or uses parts outside TOKENIZER_PARTS, is a
    ValueError naming `name`."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{name}: not a tokenizer.json (UnicodeDecodeError)") from None
    tok = Tokenizer.from_str(text, name)
    TokenizerSettings.from_tokenizer(tok, source=name)
    return tok


def check_texts(texts: list[str]) -> list[str]:
    """Reject what would silently embed to nonsense or cost without bound: a bare string, an empty list, blank
    prompts, prompts over MAX_PROMPT_CHARS characters, and strings that are not Unicode text (lone surrogates,
    which is what Python makes of command-line bytes that are not UTF-8)."""
    if isinstance(texts, str):
        raise ValueError("encode() takes a list of prompts, got a single str; wrap it: encode([text])")
    texts = list(texts)
    if not texts:
        raise ValueError("encode() got an empty list of prompts")
    for i, t in enumerate(texts):
        if not isinstance(t, str):
            raise ValueError(f"prompt {i} is a {type(t).__name__}, expected str")
        if len(t) > MAX_PROMPT_CHARS:
            raise ValueError(f"prompt {i} has {len(t):,} characters; a prompt may have at most {MAX_PROMPT_CHARS:,} "
                             f"(the text encoder reads only its first few hundred words)")
        if not t.strip():
            raise ValueError(f"prompt {i} is empty or whitespace only ({shown(t)}); describe a motion, "
                             f"e.g. 'a person walks forward'")
        try:
            t.encode("utf-8")
        except UnicodeEncodeError as e:
            raise ValueError(f"prompt {i} is not valid Unicode text: character {e.start} is a lone surrogate "
                             f"({t[e.start]!r}), as when bytes that are not UTF-8 are read as text; pass UTF-8 "
                             f"text") from None
    return texts


def check_threads(threads: int) -> int:
    """The onnxruntime thread count, an int in [1, MAX_THREADS]; what every session of the runtime is opened with."""
    return as_int("threads", threads, f"an int in [1, {MAX_THREADS}]", 1, MAX_THREADS)


def tokenize(tok: Tokenizer, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Prompts -> (input_ids, attention_mask), both (N, S) int64, S = longest prompt (<= max_length)."""
    encs = tok.encode_batch(check_texts(texts))
    ids = np.array([e.ids for e in encs], dtype=np.int64)              # (N, S)
    mask = np.array([e.attention_mask for e in encs], dtype=np.int64)  # (N, S) 1 = token, 0 = padding
    return ids, mask


def session_options(threads: int):
    """Options for sitting inside a host application: few threads, one graph at a time."""
    import onnxruntime as ort

    threads = check_threads(threads)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # onnxruntime's own warning and error lines would run into the one-line errors of `mogo`: what fails is raised and
    # reported by the runtime, naming the graph
    opts.log_severity_level = 4
    # onnxruntime's arena keeps the most any call ever took: a host whose batches vary (a crowd whose characters
    # rebuild together, a motion server restored in one tick) kept +50-100 MB it no longer used. Without it the
    # buffers go back to malloc; a crowd of 256 base characters and a single int8 clip measured no slower
    opts.enable_cpu_mem_arena = False
    if threads > 1:
        # spinning workers fight the host's own threads for the cores: 2 spinning threads measured 2-3x slower
        # than 1 thread on a busy 2-core machine, and 52% slower than 2 threads without spinning
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts


class TextEncoderSession:
    """An exported text encoder (`text_encoder.onnx` + `tokenizer.json`) on onnxruntime, CPU by default."""

    def __init__(self, onnx_path: str | Path | bytes, tokenizer_path: str | Path | bytes, threads: int = 1,
                 providers: list[str] | None = None, names: tuple[str, str] | None = None):
        """The graph and the tokenizer as paths, or as their bytes (what a bundle checked: `names` then says which
        files they are, for messages). Whatever the tokenizer or onnxruntime cannot read is a ValueError naming
        the file."""
        import onnxruntime as ort  # imported here so `tokenize` works without onnxruntime

        onnx_name, tokenizer_name = names or (str(onnx_path), str(tokenizer_path))
        data = tokenizer_path if isinstance(tokenizer_path, bytes) else Path(tokenizer_path).read_bytes()
        self.tokenizer = load_tokenizer(data, tokenizer_name)
        self.settings = TokenizerSettings.from_tokenizer(self.tokenizer, source=tokenizer_name)
        options = session_options(threads)
        try:
            self.session = ort.InferenceSession(onnx_path if isinstance(onnx_path, bytes) else str(onnx_path),
                                                options, providers=providers or ["CPUExecutionProvider"])
        except Exception as e:   # noqa: BLE001 - onnxruntime raises its own types for a file it cannot parse
            raise ValueError(f"{onnx_name}: onnxruntime cannot load it ({e})") from None
        onnx_path, tokenizer_path = onnx_name, tokenizer_name

        inputs = {i.name for i in self.session.get_inputs()}
        if inputs != {"input_ids", "attention_mask"}:
            raise ValueError(f"{onnx_path}: expected inputs input_ids, attention_mask; found {sorted(inputs)}")
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
