"""Broken bundles for js/test/broken.test.mjs, each a copy of a toy bundle with one file damaged and its hash forged
(with tests/runtime/corrupt.py's helpers): NaN weights, logits of another width declared or returned, a cache that
grows too fast, a graph onnxruntime cannot run, a tokenizer that could explode. Neither runtime loads one, or each
fails at the graph's first call, naming the file.

    python js/test/make_broken.py TOY TOY_PORTABLE OUT     # OUT/<case>/ for each case below (run.sh does this)
"""
import shutil
import sys
from pathlib import Path

import onnx
from onnx import TensorProto, helper

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "runtime"))
from corrupt import doubled_presents, failing_reshape, graph_edit, nan_weights, read_manifest, tokenizer_part  # noqa: E402


def wrap_output(g, output: str, nodes, inits=()) -> None:
    """Rename `output` inside the graph to `<output>.inner`; `nodes` (reading it) make the output anew."""
    for node in g.node:
        node.output[:] = [output + ".inner" if o == output else o for o in node.output]
    g.initializer.extend(inits)
    g.node.extend(nodes)


def ints(name: str, values) -> onnx.TensorProto:
    return helper.make_tensor(name, TensorProto.INT64, [len(values)], values)


def logits_width(delta: int, declared: bool):
    """Logits `delta` codes wider (or narrower, delta < 0). `declared`: the graph says so in its output's shape (refused
    at load); else the change depends on the batch at run time, so the graph still declares K + 1 (refused at run)."""
    def edit(g):
        out = next(o for o in g.output if o.name == "logits")
        dims = out.type.tensor_type.shape.dim
        width = dims[3].dim_value
        if declared:
            dims[3].dim_value = width + delta
            amount = [ints("amount", [abs(delta)])]
            nodes = []
        else:   # the batch (1 row here) as the amount: onnxruntime cannot infer the width
            amount = []
            nodes = [helper.make_node("Shape", ["text_embedding"], ["amount"], start=0, end=1)]
        if delta > 0:
            nodes.append(helper.make_node("Concat", ["zeros7", "amount"], ["pads"], axis=0))
            nodes.append(helper.make_node("Pad", ["logits.inner", "pads"], ["logits"]))
            inits = [ints("zeros7", [0] * 7), *amount]
        else:
            nodes.append(helper.make_node("Sub", ["full", "amount"], ["end"]))
            nodes.append(helper.make_node("Slice", ["logits.inner", "zero", "end", "axis3"], ["logits"]))
            inits = [ints("full", [width]), ints("zero", [0]), ints("axis3", [3]), *amount]
        wrap_output(g, "logits", nodes, inits)
    return edit


# case -> (which toy bundle, the damage)
CASES = {
    "nan-step": ("toy", nan_weights("step.onnx")),
    "nan-decoder": ("toy", nan_weights("decoder.onnx")),
    "wide-logits": ("toy", graph_edit("step.onnx", logits_width(1, declared=True))),
    "narrow-portable-logits": ("portable", graph_edit("step.portable.onnx", logits_width(-1, declared=True))),
    "lying-wide-logits": ("toy", graph_edit("step.onnx", logits_width(1, declared=False))),
    "lying-narrow-portable-logits": ("portable", graph_edit("step.portable.onnx", logits_width(-1, declared=False))),
    "growing-cache": ("toy", graph_edit("step.onnx", doubled_presents)),
    "decoder-fails-at-run": ("toy", graph_edit("decoder.onnx", failing_reshape)),
    "exploding-tokenizer": ("toy", tokenizer_part("normalizer", {"type": "Sequence", "normalizers": [
        {"type": "Lowercase"}, {"type": "Replace", "pattern": {"String": "a"}, "content": "a" * 200_000}]})),
}

if __name__ == "__main__":
    toy, portable, out = (Path(a) for a in sys.argv[1:4])
    for name, (source, damage) in CASES.items():
        folder = out / name
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(toy if source == "toy" else portable, folder)
        damage(folder)
        assert read_manifest(folder)["files"]     # still a manifest
    print(f"{len(CASES)} broken bundles in {out}")
