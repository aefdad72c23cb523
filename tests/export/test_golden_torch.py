"""The torch reference against the runtime on the golden cases (tests/golden/make_golden.py): on the tiny trained
bundle, the PyTorch models and the Python runtime (fp32 graphs) give identical tokens for every prompt, seed and
setting of the golden file, sampled ones included. The runtime and Node are held to the stored golden tokens on the
toy bundle, and Node to the runtime on this same tiny bundle (js/test), so torch, Python and Node agree."""
import importlib.util

from conftest import ROOT
from mogo_export.reference import TorchGenerator
from mogo_runtime import MotionGenerator
from mogo_runtime.bundle.sampling import SamplingConfig

spec = importlib.util.spec_from_file_location("make_golden", ROOT / "tests" / "golden" / "make_golden.py")
golden = importlib.util.module_from_spec(spec)
spec.loader.exec_module(golden)


def test_torch_gives_the_runtimes_tokens_on_the_golden_cases(tiny_checkpoints, tiny_bundle):
    torch_gen = TorchGenerator.from_checkpoints(tiny_checkpoints)
    runtime = MotionGenerator(tiny_bundle, variant="fp32")
    compared = steps = 0
    for case in golden.cases(["fp32"]):
        want = golden.run_case({"fp32": runtime}, case)
        sampling = SamplingConfig(**case["sampling"])
        fixed = runtime.tokens_for(case.get("seconds"))
        text, seed = case["text"], int(case["seed"])
        if isinstance(text, list) and isinstance(text[0], list):          # a timeline: one seed, prompt switches
            emb = torch_gen.backend.encode_text([t for t, _ in text])
            starts = [runtime.tokens_for(s) if s else 0 for _, s in text]
            got = [torch_gen.task(sampling, fixed).timeline(emb, starts, seed).tokens]
        else:
            got = torch_gen.generate_tokens([text] if isinstance(text, str) else text, seed, sampling, fixed)
        assert [g.tolist() for g in got] == want, f"torch differs from the runtime on {case}"
        compared += 1
        steps += sum(len(w) for w in want)
    print(f"torch = runtime on {compared} golden cases ({steps} time steps)")
    assert compared == len(golden.cases(["fp32"])) and steps > 100
