"""The typed manifest: it round-trips, and every malformed manifest ends in one clear BundleError naming the field.

The probe mutates every field of a real manifest (missing, null, a number as a string, a list where an object
belongs, zero, negative, huge, the wrong type) plus whole-file damage (JSON null, a list, deep nesting, bytes that
are not UTF-8). Each case must either load (a field that is informative only) or raise BundleError with the file
and field in its message; the CLI must print one `mogo: error:` line and exit 2, never a traceback. The manifest
probed is the toy bundle's with every optional section: streaming, the portable variant, ORT-format variants.
"""
import copy
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from toy_bundle import portable_toy_bundle, toy_bundle  # noqa: F401  (fixtures)

from mogo_runtime import Bundle, BundleError, MotionGenerator
from mogo_runtime.bundle.manifest import SCHEMA_VERSION, Manifest
from mogo_runtime.cli import main

BAD_VALUES = [None, "12", [], {}, 0, -1, True, 1e308, float("nan"), "x"]


def _paths(obj, prefix=()):
    """Every key path of a JSON value; lists contribute their first element only."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list) and obj:
        yield prefix + (0,)
        yield from _paths(obj[0], prefix + (0,))


def _mutations(manifest: dict):
    for path in _paths(manifest):
        parent = manifest
        for p in path[:-1]:
            parent = parent[p]
        if isinstance(parent, dict):
            m = copy.deepcopy(manifest)
            target = m
            for p in path[:-1]:
                target = target[p]
            del target[path[-1]]
            yield f"{'.'.join(map(str, path))} deleted", m
        for value in BAD_VALUES:
            m = copy.deepcopy(manifest)
            target = m
            for p in path[:-1]:
                target = target[p]
            if target[path[-1]] == value and type(target[path[-1]]) is type(value):
                continue
            target[path[-1]] = value
            yield f"{'.'.join(map(str, path))} = {value!r}", m


@pytest.fixture(scope="module")
def manifest_dict(portable_toy_bundle) -> dict:  # noqa: F811
    return json.loads((portable_toy_bundle / "manifest.json").read_text())


def test_manifest_round_trips(toy_bundle, manifest_dict):  # noqa: F811
    parsed = Manifest.parse(manifest_dict, "manifest.json")
    assert json.loads(json.dumps(parsed.to_dict())) == manifest_dict
    assert manifest_dict["schema_version"] == SCHEMA_VERSION
    assert parsed.past_names[:2] == ["past_key_values.0.key", "past_key_values.0.value"]
    assert parsed.present_names[-1] == f"present.{parsed.model.n_layers - 1}.value"
    assert {"streaming", "portable", "ort"} <= set(manifest_dict)
    assert parsed.fixed_cache("portable") and parsed.fixed_cache("portable_ort") and not parsed.fixed_cache("int8_ort")
    # a bundle without the optional sections (as exported before the portable variant) reads as before
    plain = json.loads((toy_bundle / "manifest.json").read_text())
    assert not {"portable", "ort"} & set(plain) and Manifest.parse(plain, "manifest.json").portable is None


def test_every_malformed_field_is_one_clear_error(portable_toy_bundle, manifest_dict, tmp_path, capsys):  # noqa: F811
    bundle = tmp_path / "bundle"
    shutil.copytree(portable_toy_bundle, bundle)
    cases = list(_mutations(manifest_dict))
    cases += [("JSON null", None), ("a list", []), ("a string", "manifest"), ("a number", 3)]
    assert len(cases) > 400
    refused, loaded = 0, []
    for name, data in cases:
        (bundle / "manifest.json").write_text(json.dumps(data))
        try:
            Bundle.load(bundle)
            loaded.append(name)
        except BundleError as e:
            refused += 1
            assert str(bundle / "manifest.json") in str(e) or str(bundle) in str(e), (name, str(e))
    # What may change and still load: informative fields, derived fields that may be left out, reference-only
    # numbers, optional settings with defaults, names of symbolic dims, a variant's quantization details.
    informative = ("producer", "model.d_model deleted", "model.end_id deleted", "model.bos_id deleted",
                   "model.pad_id deleted", "model.receptive_field = 0", "skeleton.offsets.0.0 = 0",
                   "normalization.mean.0 = ", "normalization.std.0 = ", "text_encoder.name = ",
                   "text_encoder.pooling deleted", "sampling_defaults", "variants.int8 deleted",
                   "variants.int8_fixed deleted", "variants.compact deleted", "streaming deleted", "streaming = None", "ort.onnxruntime = ")
    # the batch dim of any graph (the portable step's too) may have another name
    symbolic_dim = re.compile(r"(graphs\.\w+|portable\.step)\.(inputs|outputs)\.0\.shape\.0 = '\w+'$")
    unexpected = [n for n in loaded if not (n.startswith(informative) or symbolic_dim.match(n)
                                            or re.match(r"variants\.\w+\.\w+\.quantization", n))]
    assert not unexpected, unexpected
    assert refused >= len(cases) - len(loaded) and refused > 350
    # the new sections are probed too, and what they hold is refused when wrong
    for section in ("portable.capacity", "portable.opset", "portable.step.inputs.0", "ort.required_operators",
                    "ort.variants.int8_ort", "variants.portable_ort.step.file"):
        probed = [n for n, _ in cases if n.startswith(section) and not symbolic_dim.match(n)]
        assert probed and not set(probed) & set(loaded), (section, set(probed) & set(loaded))
    # the CLI: one line, exit 2, no traceback, on a sample of the refused cases and on raw bytes
    samples = [c for c in cases if c[0] not in loaded][::25]
    for name, data in samples:
        (bundle / "manifest.json").write_text(json.dumps(data))
        assert main(["info", str(bundle)]) == 2, name
        err = capsys.readouterr().err
        assert err.startswith("mogo: error:") and err.count("\n") == 1 and "Traceback" not in err, (name, err)
    for raw in (b"\xff\xfe not utf-8", b"[" * 100_000, b"{\"schema\": ", b""):
        (bundle / "manifest.json").write_bytes(raw)
        assert main(["info", str(bundle)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("mogo: error:") and "manifest.json" in err and err.count("\n") == 1, err


BAD_MANIFESTS = json.loads((Path(__file__).resolve().parents[1] / "golden" / "bad_manifests.json").read_text())


def edited(manifest: dict, edits: list[dict]) -> dict:
    """`manifest` with the edits of tests/golden/bad_manifests.json applied: set, delete or append at a JSON path."""
    m = copy.deepcopy(manifest)
    for edit in edits:
        (verb, path), = ((k, v) for k, v in edit.items() if k in ("set", "delete", "append"))
        parent = m
        for key in path[:-1]:
            parent = parent[key]
        if verb == "set":
            parent[path[-1]] = copy.deepcopy(edit["value"])
        elif verb == "delete":
            del parent[path[-1]]
        else:
            parent[path[-1]].append(copy.deepcopy(edit["value"]))
    return m


def test_bad_manifests_are_refused_naming_the_field(manifest_dict, capsys):
    """Every case of the table that the JavaScript runtime's tests run too (js/test/manifest.test.mjs)."""
    for name, setup in BAD_MANIFESTS["setups"].items():   # a setup alone parses: the cases fail for their own edit
        assert Manifest.parse(edited(manifest_dict, setup), "bundle/manifest.json"), name
    cases = BAD_MANIFESTS["cases"]
    for case in cases:
        m = edited(manifest_dict, BAD_MANIFESTS["setups"].get(case.get("with"), []) + case["edit"])
        with pytest.raises(BundleError) as e:
            Manifest.parse(m, "bundle/manifest.json")
        message = str(e.value)
        assert case["names"] in message and message.startswith("bundle/manifest.json: "), (case["why"], message)
    with capsys.disabled():
        print(f"\nbad manifests: {len(cases)} cases of tests/golden/bad_manifests.json refused, each naming its field")


def test_a_symlinked_or_swapped_graph_is_refused(toy_bundle, tmp_path):  # noqa: F811
    bundle = tmp_path / "bundle"
    shutil.copytree(toy_bundle, bundle)
    outside = tmp_path / "outside.onnx"
    shutil.copy(bundle / "lookup.onnx", outside)
    (bundle / "lookup.onnx").unlink()
    (bundle / "lookup.onnx").symlink_to(outside)
    with pytest.raises(BundleError, match="not a regular file"):
        Bundle.load(bundle)
    # a graph from another model: same I/O, but its mogo.* facts disagree with this manifest
    shutil.rmtree(bundle)
    shutil.copytree(toy_bundle, bundle)
    import onnx

    g = onnx.load(str(bundle / "decoder.onnx"))
    onnx.helper.set_model_props(g, {"graph": "decoder", "mogo.downsample": "8"})
    onnx.save(g, str(bundle / "decoder.onnx"))
    m = json.loads((bundle / "manifest.json").read_text())
    import hashlib

    data = (bundle / "decoder.onnx").read_bytes()
    m["files"]["decoder.onnx"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    (bundle / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(BundleError, match="metadata mogo.downsample is '8'"):
        MotionGenerator(bundle)


def test_the_generator_reads_the_typed_manifest(toy_bundle):  # noqa: F811
    gen = MotionGenerator(toy_bundle)
    m = gen.bundle.manifest
    assert gen.sampling_defaults == m.sampling_defaults and gen.max_tokens == m.model.max_tokens
    assert np.isfinite(gen.generate("a person walks", seconds=0.4).joints).all()
