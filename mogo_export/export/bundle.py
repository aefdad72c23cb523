"""Write a bundle: every graph, the tokenizer, the int8, portable and compact variants, their ORT-format copies and a
manifest, atomically (docs/bundle.md).

    mogo-export export checkpoints/base --out bundles/base [--opset 20] [--int8 step,text_encoder]
                                        [--no-portable] [--ort int8,portable]

Opsets: the dynamic step graphs at `--opset`; the text encoder, lookup and decoders at min(opset, 17), so that one
file serves every variant, the portable one included (at 17 instead of 20 the text encoder differs by 1e-7 and runs
as fast on base); the portable step at the same opset as they.

The bundle is built in a hidden sibling folder and renamed into place only when complete, so a crash never
leaves a half-written bundle looking finished.
"""
from __future__ import annotations

import json
import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import onnxscript
import tokenizers
import torch
from onnxruntime.quantization import QuantType, quantize_dynamic

from mogo_runtime.bundle.folder import sha256_file
from mogo_runtime.bundle.manifest import (COMPACT, INT8_FIXED, ORT_SUFFIX, PORTABLE, SCHEMA, SCHEMA_VERSION,
                                          Manifest)
from mogo_runtime.bundle.sampling import SamplingConfig
from mogo_runtime.bundle.sections import (PER_ROW_INT8, PORTABLE_OPSET, WEIGHT_INT8, ControlSpec, GraphFile,
                                          GraphSpec, Normalization, OrtFormat, PortableSpec, Quantization,
                                          StreamingSpec, TensorSpec, TextEncoderSpec, required_capacity)
from mogo_runtime.kinematics.skeleton import get_skeleton
from mogo_runtime.outputs.files import process_alive, write_atomic

from .. import __version__
from ..checkpoint import load_trained, model_dims
from ..models.text_encoder import get_text_encoder
from .caption_index import build_caption_index, tca_manifest_section
from .graphs import DEFAULT_OPSET, export_decoder, export_decoder_step, export_lookup, export_step
from .opset import portable_problems
from .ort_format import to_ort, write_required_operators
from .portable import export_portable_step
from .rowquant import quantize_per_row
from .text_encoder import export_text_encoder, quantize_text_encoder
from .weightquant import COMPACT_OPSET, write_compact

INT8_GRAPHS = ("step", "text_encoder")  # lookup and decoder stay fp32: ConvInteger ran slower than fp32 here
ORT_VARIANTS = ("int8", PORTABLE)       # variants also written in ORT format, for an onnxruntime minimal build
REQUIRED_OPERATORS = "required_operators.config"
# Classifier-free guidance 2 with top_p 0.8, measured on `base` (int8, 10-minute streams, 3 seeds; README): endless
# streams follow their prompts 0.94 of the time (guidance 1, top_p 0.95: 0.84 on one seed), single clips 0.96
# (0.90 before), at two step rows per token. Guidance 3 followed best (0.97) but its feet skated 4 points more
# than the data's; 2 with top_p 0.8 stays within about 2.
# int8 weights in 7 bits ([-64, 63]), for every CPU: onnxruntime's u8 x s8 kernel on x86 without VNNI (AVX2 and
# AVX-512BW: Haswell to Comet Lake, Zen 1-3) adds pairs of products in int16 with saturation, and 255 * 127 * 2
# overflows it; 255 * 64 * 2 does not. Measured on base's int8 graphs (benchmarks/cpu_kinds.py): with 8-bit weights
# an emulated Haswell gave step logits 1.59 and text embeddings 0.023 off the native (VNNI) numbers from the same
# inputs; with 7-bit weights, identical. The step ran as fast natively (3.30 vs 3.48 ms, 20 calls). u8 x u8 weights
# (QUInt8) were also exact on Haswell but 1.6x slower natively (5.65 ms).
INT8_REDUCE_RANGE = True
SAMPLING_DEFAULTS = SamplingConfig(temperature=1.0, top_k=None, top_p=0.8, guidance=2.0)


def sampling_defaults(transformer_meta: dict) -> SamplingConfig:
    """The bundle's default sampling: a transformer distilled to give guidance g in its conditional row
    (distill.py) samples with one row (guidance 1) at the same top_p; guidance on top stays available."""
    if "distilled" in transformer_meta:
        return SamplingConfig(temperature=SAMPLING_DEFAULTS.temperature, top_k=SAMPLING_DEFAULTS.top_k,
                              top_p=SAMPLING_DEFAULTS.top_p, guidance=1.0)
    return SAMPLING_DEFAULTS


def _graph_spec(io: dict) -> GraphSpec:
    return GraphSpec(*(tuple(TensorSpec(d["name"], d["dtype"], tuple(d["shape"])) for d in io[k])
                       for k in ("inputs", "outputs")))


def quantize_step(fp32: Path, int8: Path) -> dict:
    """Dynamic int8 for the step graph: MatMuls with constant weights, QInt8, per output channel, 7-bit weights
    (INT8_REDUCE_RANGE). Per-channel fails at run time on 3-D weights (FACTS.md), but every transformer weight is 2-D
    (a test checks it); on the base model it raised int8/fp32 greedy token agreement from 0.70 to 0.81 and cut joint
    error 44 -> 13 mm."""
    options = {"per_channel": True, "weight_type": "QInt8", "reduce_range": INT8_REDUCE_RANGE,
               "op_types": ["MatMul", "Gemm"]}
    # The quantizer rewrites Gemm weights in place, and the exporter's value_info for those initializers then
    # contradicts shape inference ("Inferred shape and existing shape differ"): quantize a copy without it.
    model = onnx.load(str(fp32))
    del model.graph.value_info[:]
    bare = int8.with_suffix(".bare.onnx")
    onnx.save(model, str(bare))
    try:
        quantize_dynamic(str(bare), str(int8), per_channel=True, weight_type=QuantType.QInt8,
                         reduce_range=INT8_REDUCE_RANGE, op_types_to_quantize=["MatMul", "Gemm"])
    finally:
        bare.unlink(missing_ok=True)
    return options


def quantize_step_per_row(fp32: Path, int8: Path) -> dict:
    """quantize_step, then one activation scale per row (rowquant.py): int8 whose rows never depend on their
    batch. On base's portable step, teacher-forced argmax agreement with fp32 0.986 (per-tensor: 0.986 on the
    same graph, 0.977 on the dynamic step), over 36 prompts, 1,263 steps."""
    options = quantize_step(fp32, int8)
    onnx.save(quantize_per_row(onnx.load(str(int8))), str(int8))
    return options


def _write_ort(folder: Path, variants: dict, names: tuple[str, ...], log) -> OrtFormat:
    """Variant `v` of `names` also as `v_ort`, every graph file converted to ORT format (x.onnx -> x.ort, each file
    once), plus the minimal build's operator list of all of them. Adds the variants to `variants`."""
    converted: dict[str, Path] = {}
    for v in names:
        log(f"converting the {v} variant to ORT format ...")
        for entry in variants[v].values():
            if entry.file not in converted:
                converted[entry.file] = folder / (Path(entry.file).stem + ORT_SUFFIX)
                to_ort(folder / entry.file, converted[entry.file])
        variants[f"{v}_ort"] = {g: GraphFile(converted[e.file].name, e.quantization) for g, e in variants[v].items()}
    write_required_operators(sorted(set(converted.values())), folder / REQUIRED_OPERATORS)
    return OrtFormat(required_operators=REQUIRED_OPERATORS, variants={f"{v}_ort": v for v in names},
                     onnxruntime=onnxruntime.__version__)


def remove_dead_partials(out: Path) -> list[Path]:
    """Remove the `.NAME.partial-PID` folders beside bundle `out` whose exporter is gone (killed mid-way):
    a live exporter's folder is kept. Returns what was removed."""
    removed = []
    for stale in sorted(out.parent.glob(f".{out.name}.partial-*")):
        pid = stale.name.rsplit("-", 1)[1]
        if pid.isdigit() and not process_alive(int(pid)):
            shutil.rmtree(stale, ignore_errors=True)
            removed.append(stale)
    return removed


def export_bundle(ckpt_dir: str | Path, out: str | Path, opset: int = DEFAULT_OPSET,
                  int8: tuple[str, ...] = INT8_GRAPHS, portable: bool = True, ort: tuple[str, ...] = ORT_VARIANTS,
                  data: str | Path | None = None, log=print) -> Path:
    """`data`: the dataset whose training captions become the TCA caption index (default: the one the
    checkpoints were trained on, as recorded in them). Without it the bundle has no index and says so.
    `portable`: write the portable variant; `ort`: the variants to also write in ORT format."""
    ckpt_dir, out = Path(ckpt_dir), Path(out)
    unknown = set(int8) - set(INT8_GRAPHS)
    if unknown:
        raise ValueError(f"--int8 accepts {list(INT8_GRAPHS)}; got {sorted(unknown)}")
    if set(ort) - set(ORT_VARIANTS) or (PORTABLE in ort and not portable):
        raise ValueError(f"--ort accepts {list(ORT_VARIANTS)} (portable only with the portable variant); got "
                         f"{list(ort)}")
    trained = load_trained(ckpt_dir)  # every meta field checked; no defaults
    vq, tr, vq_payload, tr_payload = trained.vq, trained.transformer, trained.vq_payload, trained.transformer_payload
    meta = vq_payload["meta"]
    fps = trained.fps
    skeleton = get_skeleton(trained.skeleton)
    dims = model_dims(vq, tr, fps, trained.max_tokens)
    encoder = get_text_encoder(trained.text_encoder_name)
    if encoder.dim != dims.text_dim:
        raise ValueError(f"text encoder {encoder.name!r} gives {encoder.dim}-dim embeddings, the transformer "
                         f"expects {dims.text_dim}")

    out.parent.mkdir(parents=True, exist_ok=True)
    remove_dead_partials(out)
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        # every graph carries the model facts; the runtime checks them against the manifest when it loads one
        graph_meta = {"mogo.schema": SCHEMA, "mogo.schema_version": SCHEMA_VERSION, "mogo.producer": __version__,
                      **{f"mogo.{k}": v for k, v in dims.to_dict().items()}}
        t0 = time.perf_counter()
        shared_opset = min(opset, PORTABLE_OPSET)      # text encoder, lookup, decoder: one file for every variant
        graphs, variants = {}, {"fp32": {}, "int8": {}}
        log("exporting text_encoder ...")
        te = export_text_encoder(encoder, tmp, shared_opset)
        graphs["text_encoder"] = {"inputs": te["inputs"], "outputs": te["outputs"]}
        log("exporting step, lookup, decoder, decoder_step ...")
        graphs["step"] = export_step(tr, tmp / "step.onnx", opset, {**graph_meta, "mogo.graph": "step"})
        graphs["lookup"] = export_lookup(vq, tmp / "lookup.onnx", shared_opset,
                                         {**graph_meta, "mogo.graph": "lookup"})
        graphs["decoder"] = export_decoder(vq, meta["mean"], meta["std"], tmp / "decoder.onnx", shared_opset,
                                           {**graph_meta, "mogo.graph": "decoder"})
        graphs["decoder_step"] = export_decoder_step(vq, meta["mean"], meta["std"], tmp / "decoder_step.onnx",
                                                     shared_opset, {**graph_meta, "mogo.graph": "decoder_step"})
        tca = None
        data_root = Path(data) if data is not None else Path(meta.get("dataset", ""))
        if data is not None or (data_root.name and (data_root / "train.txt").exists()):
            log(f"building the TCA caption index from {data_root} ...")
            tca = tca_manifest_section(build_caption_index(data_root, encoder, tmp / "captions.npz"))
        else:
            log(f"no TCA caption index: dataset {data_root} not found (pass data=... / --data)")
        for g in graphs:
            variants["fp32"][g] = GraphFile(f"{g}.onnx")
            variants["int8"][g] = GraphFile(f"{g}.onnx")
        for g in int8:
            log(f"quantizing {g} to int8 ...")
            fp32, q = tmp / f"{g}.onnx", tmp / f"{g}.int8.onnx"
            options = (quantize_text_encoder(fp32, q, INT8_REDUCE_RANGE) if g == "text_encoder"
                       else quantize_step(fp32, q))
            variants["int8"][g] = GraphFile(q.name, Quantization("onnxruntime.quantize_dynamic", options))
        portable_spec = None
        if portable:
            capacity = required_capacity(dims, StreamingSpec(**trained.streaming) if trained.streaming else None)
            log(f"exporting the portable step (cache of {capacity} steps, opset {shared_opset}) ...")
            io = export_portable_step(tr, tmp / "step.portable.onnx", capacity, shared_opset,
                                      {**graph_meta, "mogo.graph": "step", "mogo.capacity": capacity})
            variants[PORTABLE] = {**variants["fp32"], "step": GraphFile("step.portable.onnx")}
            portable_spec = PortableSpec(capacity=capacity, opset=shared_opset, step=_graph_spec(io))
            for g, entry in variants[PORTABLE].items():
                problems = portable_problems(onnx.load(str(tmp / entry.file)), shared_opset)
                if problems:
                    raise RuntimeError(f"{entry.file} cannot be in the portable variant: {'; '.join(problems)}")
            if "step" in int8:
                log("quantizing the portable step to per-row int8 ...")
                options = quantize_step_per_row(tmp / "step.portable.onnx", tmp / "step.portable.int8.onnx")
                variants[INT8_FIXED] = {**variants["int8"], "step": GraphFile("step.portable.int8.onnx",
                                                                             Quantization(PER_ROW_INT8, options))}
            log(f"writing the compact variant (int8-stored weights, float32 arithmetic, opset {COMPACT_OPSET}) ...")
            variants[COMPACT] = {}
            for g, entry in variants[PORTABLE].items():
                options = write_compact(tmp / entry.file, tmp / f"{g}.compact.onnx")
                variants[COMPACT][g] = GraphFile(f"{g}.compact.onnx", Quantization(WEIGHT_INT8, options))
        ort_format = _write_ort(tmp, variants, ort, log) if ort else None
        te_meta = te.get("metadata", {})
        manifest = Manifest(
            producer={"name": "mogo-export", "version": __version__, "torch": torch.__version__,
                         "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__,
                         "onnxscript": onnxscript.__version__, "python": platform.python_version(),
                         # the normative tokenizer (docs/bundle.md, "Tokenising, exactly"): its Unicode tables
                         "tokenizers": tokenizers.__version__,
                         "opset": opset, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                         "checkpoints": {"vq_step": vq_payload["train"].get("step"),
                                         "transformer_step": tr_payload["train"].get("step"),
                                         "preset": meta.get("preset"),
                                         "learnable_scaling": vq.cfg.learnable_scaling,
                                         # the guidance its conditional row learned (distill.py), if any
                                         "distilled": tr_payload["meta"].get("distilled"),
                                         # the control adapter inside the step graphs (adapter.py), if any
                                         "adapter": tr_payload["meta"].get("adapter")}},
            model=dims,
            skeleton=skeleton,
            normalization=Normalization(mean=tuple(np.round(meta["mean"], 7).tolist()),
                                        std=tuple(np.round(meta["std"], 7).tolist())),
            text_encoder=TextEncoderSpec(name=encoder.name, tokenizer="tokenizer.json",
                                         max_length=int(te_meta["max_length"]), pooling=te_meta.get("pooling", "mean")),
            sampling_defaults=sampling_defaults(tr_payload["meta"]),
            tca=tca,
            streaming=StreamingSpec(**trained.streaming) if trained.streaming else None,
            control=ControlSpec(tr.cfg.control_horizon, tr.cfg.control_dim) if tr.cfg.control_dim else None,
            graphs={g: _graph_spec(io) for g, io in graphs.items()},
            variants=variants,
            portable=portable_spec,
            ort=ort_format,
            files={p.name: (p.stat().st_size, sha256_file(p)) for p in sorted(tmp.iterdir())},
        )
        text = json.dumps(manifest.to_dict(), indent=2) + "\n"
        Manifest.parse(json.loads(text), str(out / "manifest.json"))     # what is written must read back
        write_atomic(tmp / "manifest.json", lambda f: f.write(text.encode()))
        if out.exists():  # replace an older bundle only now that the new one is complete
            old = out.parent / f".{out.name}.old-{os.getpid()}"
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old)
        else:
            tmp.rename(out)
        log(f"bundle written to {out} in {time.perf_counter() - t0:.1f} s")
        return out
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
