"""Graphs in onnxruntime's ORT format, and the operator list of an onnxruntime minimal build that runs them.

    to_ort(Path("bundle/step.int8.onnx"), Path("bundle/step.int8.ort"))
    write_required_operators([Path("bundle/step.int8.ort"), ...], Path("bundle/required_operators.config"))

What `python -m onnxruntime.tools.convert_onnx_models_to_ort` does with its defaults (optimization style Fixed,
level all, no NCHWc layout, which would tie a file to x86), one file at a time so the names are ours: the graph
is optimized as a session would at load and saved in ORT format; the config lists every operator of the .ort
files, for `build.sh --minimal_build --include_ops_by_config required_operators.config`.
"""
from __future__ import annotations

import logging
import tempfile
from pathlib import Path

import onnxruntime as ort
from onnxruntime.tools.ort_format_model import create_config_from_models


def to_ort(onnx_path: Path, ort_path: Path) -> None:
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.optimized_model_filepath = str(ort_path)
    so.add_session_config_entry("session.save_model_format", "ORT")
    so.add_session_config_entry("session.qdqisint8allowed", "0")    # the tool's default off ARM
    ort.InferenceSession(str(onnx_path), so, providers=["CPUExecutionProvider"],
                         disabled_optimizers=["NchwcTransformer"])
    if not ort_path.is_file():
        raise RuntimeError(f"onnxruntime wrote no ORT-format file for {onnx_path}")


def write_required_operators(ort_paths: list[Path], config: Path) -> None:
    """The operators (per domain and opset) of `ort_paths`, in the format a minimal build reads. The header
    names the files without their folder (the tool writes absolute paths, here a temporary folder's)."""
    log = logging.getLogger("ort_format_model.utils")    # it logs the temporary path at INFO
    level = log.level
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / config.name
        log.setLevel(logging.WARNING)
        try:
            create_config_from_models(ort_paths, raw, False)
        finally:
            log.setLevel(level)
        by_path = {str(p): p.name for p in ort_paths}
        lines = [f"# - {by_path.get(line[4:], line[4:])}" if line.startswith("# - ") else line
                 for line in raw.read_text().splitlines()]
    config.write_text("\n".join(lines) + "\n")
