"""Corrupt and hostile bundles (tests/runtime/corrupt.py): every case ends in a finite motion or a BundleError /
ValueError naming the file or field, within a time bound, and nothing outside the bundle folder is opened."""
import collections

import pytest

from corrupt import external_data, fixed_cases, nan_weights, run_case
from mogo_runtime import BundleError
from toy_bundle import toy_bundle  # noqa: F401

TIME_LIMIT_S = 20.0


def test_every_corrupt_bundle_is_refused_clearly_or_runs_finite(toy_bundle, tmp_path):  # noqa: F811
    cases = fixed_cases(toy_bundle)
    counts, bad = collections.Counter(), []
    slowest = (0.0, "")
    for n, (name, case) in enumerate(cases.items()):
        result, detail, took = run_case(toy_bundle, tmp_path / f"c{n}", case, TIME_LIMIT_S)
        counts[result] += 1
        slowest = max(slowest, (took, name))
        if result not in ("ok", "refused"):
            bad.append(f"{name}: {result}: {detail[:300]}")
    print(f"{len(cases)} corrupt bundles: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) +
          f"; slowest {slowest[0]:.2f} s ({slowest[1]})")
    assert not bad, "\n".join(bad)
    assert counts["refused"] > len(cases) // 2     # the suite does damage things


def _damaged(toy_bundle, tmp_path, case):  # noqa: F811
    import shutil
    folder = tmp_path / "bundle"
    shutil.copytree(toy_bundle, folder)
    case(folder)
    return folder


@pytest.mark.parametrize("graph", ["text_encoder.onnx", "step.onnx", "lookup.onnx", "decoder.onnx"])
def test_nan_weights_never_reach_a_motion_and_the_error_names_the_graph(toy_bundle, tmp_path, graph):  # noqa: F811
    from mogo_runtime import MotionGenerator
    from mogo_runtime.engine import NonFiniteOutput
    folder = _damaged(toy_bundle, tmp_path, nan_weights(graph))
    gen = MotionGenerator(folder)
    with pytest.raises(NonFiniteOutput, match=f"{graph}: the {graph.split('.')[0]} graph produced NaN or inf"):
        gen.generate("a person walks forward", seconds=1)
    with pytest.raises(NonFiniteOutput):
        list(gen.stream("a person walks forward", seconds=1))


@pytest.mark.parametrize("outside", [False, True])
def test_a_graph_with_external_data_is_refused(toy_bundle, tmp_path, outside):  # noqa: F811
    from mogo_runtime import MotionGenerator
    folder = _damaged(toy_bundle, tmp_path, external_data("decoder.onnx", outside))
    with pytest.raises(BundleError, match="decoder.onnx: keeps tensors in external-data files.*self-contained"):
        MotionGenerator(folder)


def test_a_graph_replaced_after_loading_is_not_run(toy_bundle, tmp_path):  # noqa: F811
    """The bytes onnxruntime parses are the bytes whose hash was checked: a swap between the check and the
    session is caught."""
    from mogo_runtime import Bundle
    from mogo_runtime.engine import OrtBackend
    folder = _damaged(toy_bundle, tmp_path, lambda f: None)
    bundle = Bundle.load(folder)                              # hashes checked here
    step = folder / "step.onnx"
    data = bytearray(step.read_bytes())
    data[-1] ^= 1                                             # same size, other bytes
    step.write_bytes(bytes(data))
    with pytest.raises(BundleError, match="step.onnx: sha256 does not match the manifest"):
        OrtBackend(bundle, "fp32")


def test_the_cli_refuses_a_corrupt_bundle_in_one_line(toy_bundle, tmp_path, capsys):  # noqa: F811
    from mogo_runtime.cli import main
    folder = _damaged(toy_bundle, tmp_path, nan_weights("decoder.onnx"))
    code = main(["generate", "a person walks", "--bundle", str(folder), "--seconds", "1", "-o", str(tmp_path / "x.npy")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("mogo: error:") and "decoder.onnx" in err
    assert not (tmp_path / "x.npy").exists()
