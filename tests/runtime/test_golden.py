"""The golden tokens (tests/golden/toy.json) from the Python runtime: the same toy bundle, prompts, seeds and
settings must give exactly the stored tokens (Node and the browser are held to the same file); and the controlled
streams of tests/golden/toy_control.json, on the toy bundle whose model has control."""
import importlib.util
import json

import pytest
from toy_bundle import control_toy_bundle, toy_bundle  # noqa: F401  (fixtures)

from conftest import ROOT
from mogo_runtime import MotionGenerator

spec = importlib.util.spec_from_file_location("make_golden", ROOT / "tests" / "golden" / "make_golden.py")
golden_module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(golden_module)
GOLDEN = json.loads(golden_module.GOLDEN.read_text())
GOLDEN_CONTROL = json.loads(golden_module.GOLDEN_CONTROL.read_text())


@pytest.fixture(scope="module")
def generators(toy_bundle):  # noqa: F811
    # a different bundle is a different test: say so rather than report token mismatches
    assert golden_module.bundle_hashes(toy_bundle) == GOLDEN["files"], \
        "the toy bundle changed since tests/golden/toy.json was written: regenerate it (tests/golden/make_golden.py)"
    return {v: MotionGenerator(toy_bundle, variant=v) for v in ("fp32", "int8")}


def test_the_python_runtime_gives_the_golden_tokens(generators):
    cases = GOLDEN["cases"]
    planned = len(golden_module.planned_cases(["fp32", "int8"]))
    assert len(cases) == len(golden_module.cases(["fp32", "int8"])) + planned and len(cases) > 100
    wrong = [(i, c["variant"], c["text"], c["seed"], c["sampling"]) for i, c in enumerate(cases)
             if golden_module.case_results(generators, c) != golden_module.results(c)]
    steps = sum(len(t) for c in cases for t in c["tokens"])
    print(f"golden: {len(cases) - len(wrong)} of {len(cases)} cases ({steps} time steps; {planned} with prompts of "
          f"several actions) identical")
    assert not wrong, f"{len(wrong)} cases differ, first: {wrong[:3]}"


def test_controlled_streams_give_the_golden_tokens(control_toy_bundle):  # noqa: F811
    variants = golden_module.CONTROL_VARIANTS
    assert golden_module.bundle_hashes(control_toy_bundle, variants) == GOLDEN_CONTROL["files"], \
        "the control toy bundle changed since tests/golden/toy_control.json was written: regenerate it"
    generators = {v: MotionGenerator(control_toy_bundle, variant=v) for v in variants}
    cases = GOLDEN_CONTROL["cases"]
    assert len(cases) == len(golden_module.control_cases(variants))
    fields = ("tokens", "controls", "landed", "arrived")
    wrong = [(i, c["variant"], c["seed"], c["sampling"]) for i, c in enumerate(cases)
             if golden_module.run_control_case(generators, c) != {k: c[k] for k in fields}]
    steps = sum(len(c["tokens"]) for c in cases)
    print(f"golden control: {len(cases) - len(wrong)} of {len(cases)} controlled streams ({steps} tokens) identical")
    assert not wrong, f"{len(wrong)} controlled streams differ, first: {wrong[:3]}"
