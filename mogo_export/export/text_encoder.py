"""Export a text encoder to `text_encoder.onnx` + `tokenizer.json` (and optionally `text_encoder.int8.onnx`).

    from mogo_export.models.text_encoder import get_text_encoder
    from mogo_export.export.text_encoder import export_text_encoder, quantize_text_encoder
    info = export_text_encoder(get_text_encoder("all-MiniLM-L6-v2"), "bundle/")
    quantize_text_encoder("bundle/text_encoder.onnx", "bundle/text_encoder.int8.onnx", reduce_range=True)

The graph:
    input_ids       int64   (batch, sequence)   token ids from tokenizer.json
    attention_mask  int64   (batch, sequence)   1 for tokens, 0 for padding
    text_embedding  float32 (batch, dim)        pooled and (per metadata) L2-normalised
Its metadata_props hold encoder, dim, pooling, normalized, max_length, padding; `mogo_runtime.text` reads them.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import onnx
import torch

from mogo_runtime.text import TokenizerSettings, tokenize

from .graphs import io_spec
from .opset import TORCH_MIN_OPSET, default_opset, to_opset

INPUTS = ("input_ids", "attention_mask")
OUTPUT = "text_embedding"
_TRACE_TEXTS = ["a person walks forward", "a man waves his left hand and then jumps twice"]  # batch 2, S > 2

def _set_metadata(model: onnx.ModelProto, meta: dict[str, str]) -> None:
    kept = [p for p in model.metadata_props if p.key not in meta]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    onnx.helper.set_model_props(model, {**{p.key: p.value for p in kept}, **meta})


def export_text_encoder(encoder, out_dir: str | Path, opset: int = 20) -> dict:
    """Write out_dir/text_encoder.onnx (one file) and out_dir/tokenizer.json; return their I/O description.

    `encoder` must be an nn.Module with forward(input_ids, attention_mask) -> (N, dim) and attributes
    name, dim, pooling, tokenizer (configured tokenizers.Tokenizer), tokenizer_settings.
    """
    for attr in ("name", "dim", "pooling", "tokenizer", "tokenizer_settings"):
        if not hasattr(encoder, attr):
            raise TypeError(f"{type(encoder).__name__} lacks .{attr}; see mogo_export/models/text_encoder.py "
                            f"for what an exportable text encoder provides")
    if not isinstance(encoder, torch.nn.Module):
        raise TypeError(f"{type(encoder).__name__} is not an nn.Module; only its forward() can be exported")
    settings: TokenizerSettings = encoder.tokenizer_settings
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    onnx_path, tok_path = out_dir / "text_encoder.onnx", out_dir / "tokenizer.json"

    # Trace with batch 2 and sequence > 2: a dynamic dim traced at size 0 or 1 is silently fixed (FACTS.md).
    ids, mask = tokenize(encoder.tokenizer, _TRACE_TEXTS)
    batch = torch.export.Dim("batch", min=1, max=4096)
    seq = torch.export.Dim("sequence", min=1, max=settings.max_length)
    was_training = encoder.training
    encoder.eval()
    with torch.no_grad(), warnings.catch_warnings():
        # torch notes that "batch"/"sequence" are shared by both inputs; the names are kept all the same
        warnings.filterwarnings("ignore", message=".*axis name.*will not be used")
        torch.onnx.export(
            encoder, (torch.from_numpy(ids), torch.from_numpy(mask)), str(onnx_path),
            dynamo=True, opset_version=max(opset, TORCH_MIN_OPSET), external_data=False, verbose=False,
            input_names=list(INPUTS), output_names=[OUTPUT],
            dynamic_shapes={"input_ids": {0: batch, 1: seq}, "attention_mask": {0: batch, 1: seq}},
        )
    encoder.train(was_training)

    model = to_opset(onnx.load(str(onnx_path)), opset)   # torch itself would silently keep 18 (opset.py)
    if default_opset(model) != opset:
        raise RuntimeError(f"{onnx_path}: exported at opset {default_opset(model)}, asked for {opset}")
    _set_metadata(model, {
        "encoder": encoder.name,
        "dim": str(encoder.dim),
        "pooling": encoder.pooling,
        "normalized": "true",
        "max_length": str(settings.max_length),
        "padding": "longest",
        "pad_token": settings.pad_token,
    })
    onnx.save(model, str(onnx_path))
    onnx.checker.check_model(str(onnx_path), full_check=True)

    spec = io_spec(model)
    inputs, outputs = spec["inputs"], spec["outputs"]
    if [i["name"] for i in inputs] != list(INPUTS) or [o["name"] for o in outputs] != [OUTPUT]:
        raise RuntimeError(f"{onnx_path}: unexpected I/O names {inputs} -> {outputs}")
    for io in inputs:
        if not all(isinstance(d, str) and d for d in io["shape"]):
            raise RuntimeError(f"{onnx_path}: input {io['name']} has shape {io['shape']}; batch and sequence "
                               f"must be symbolic (was a dim traced at size 0 or 1?)")
    if not isinstance(outputs[0]["shape"][0], str) or outputs[0]["shape"][1] != encoder.dim:
        raise RuntimeError(f"{onnx_path}: output shape {outputs[0]['shape']}, expected [batch, {encoder.dim}]")

    encoder.tokenizer.save(str(tok_path))  # already carries truncation and padding (configure_tokenizer)
    return {
        "onnx": onnx_path.name, "tokenizer": tok_path.name, "opset": opset,
        "inputs": inputs, "outputs": outputs,
        "metadata": {p.key: p.value for p in model.metadata_props},
    }


def quantize_text_encoder(fp32_path: str | Path, int8_path: str | Path, reduce_range: bool) -> dict:
    """Dynamic int8 (weights int8 per output channel, 7-bit with `reduce_range`, activations quantised at run time);
    returns the options.

    per_channel=True keeps cosine >= 0.98 to fp32 on MiniLM; per-tensor drops to ~0.85 (FACTS.md).
    """
    from onnxruntime.quantization import QuantType, quantize_dynamic

    options = {"per_channel": True, "weight_type": "QInt8", "reduce_range": reduce_range}
    quantize_dynamic(str(fp32_path), str(int8_path), per_channel=True, weight_type=QuantType.QInt8,
                     reduce_range=reduce_range, use_external_data_format=False)
    # keep the fp32 graph's facts (dim, max_length, ...) so the runtime can read either file the same way
    meta = {p.key: p.value for p in onnx.load(str(fp32_path), load_external_data=False).metadata_props}
    model = onnx.load(str(int8_path))
    _set_metadata(model, {**meta, "quantization": "dynamic-int8-per-channel"})
    onnx.save(model, str(int8_path))
    onnx.checker.check_model(str(int8_path))
    return options
