"""The second hardening pass: each case an attack or misuse that once got through (a file followed through a link,
an index swapped after its hash was checked, hostile rig files and stdin, a tokenizer that explodes, graphs whose
outputs lie, names too long for a file system, crowds and streams used from two threads) and what happens now.

Runs with torch blocked, on the toy bundles.
"""
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from corrupt import doubled_presents, failing_reshape, graph_edit, read_manifest, rehash, write_manifest
from test_tca import add_caption_index
from toy_bundle import portable_toy_bundle, toy_bundle  # noqa: F401  (fixtures)

from mogo_runtime import BundleError, MotionGenerator, SamplingConfig
from mogo_runtime.bundle.sections import StreamingSpec
from mogo_runtime.cli import main
from mogo_runtime.crowd import Crowd
from mogo_runtime.endless import EndlessLoop
from mogo_runtime.outputs.rig import RigError, load_rig

WALK, JUMP = "a person walks forward", "a person jumps twice"


def copy_of(bundle: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "b"
    shutil.copytree(bundle, dst)
    return dst


def one_error_line(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("mogo: error:") and err.count("\n") == 1 and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------------------------------------- integrity

def test_a_manifest_that_is_a_link_is_refused_unread(toy_bundle, tmp_path):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    elsewhere = tmp_path / "elsewhere.json"
    (b / "manifest.json").rename(elsewhere)
    (b / "manifest.json").symlink_to(elsewhere)              # a valid manifest: it loaded and generated before
    with pytest.raises(BundleError, match=r"manifest.json: a link, which is not allowed here"):
        MotionGenerator(b)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)                                           # followed, opening it would block for ever
    (b / "manifest.json").unlink()
    (b / "manifest.json").symlink_to(fifo)
    with pytest.raises(BundleError, match="a link"):
        MotionGenerator(b)


def test_a_caption_index_swapped_after_loading_is_refused(toy_bundle, tmp_path):  # noqa: F811
    b = add_caption_index(toy_bundle, tmp_path / "indexed")
    gen = MotionGenerator(b)                                  # the index is read on the first align=True
    other = add_caption_index(toy_bundle, tmp_path / "other", dtype="int8")     # valid, other bytes
    shutil.copy(other / "captions.npz", b / "captions.npz")
    with pytest.raises(BundleError, match=r"captions.npz: (size \d+ bytes, manifest says|sha256 does not match)"):
        gen.generate(WALK, seed=0, align=True)


# ---------------------------------------------------------------------------------------- rig files

def test_rig_files_that_are_devices_pipes_bombs_or_wrongly_typed_are_refused(tmp_path):
    zero = tmp_path / "zero.json"
    zero.symlink_to("/dev/zero")                              # its size reads 0: a size check alone reads for ever
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 300_000)
    start = time.perf_counter()
    for path, message in ((zero, "not a regular file"), (fifo, "not a regular file"),
                          (deep, "not a JSON rig file")):
        with pytest.raises(RigError, match=message):
            load_rig(str(path))
    assert time.perf_counter() - start < 5
    rig = load_rig("mixamo").to_dict()
    for edit, field in ((lambda r: r.update(bone_axis=["x"]), "bone_axis"),
                        (lambda r: r["bones"][0].update(source=["pelvis"]), r"bones\[0\].source"),
                        (lambda r: [b.pop("source", None) for b in r["bones"] if b.get("source") == "left_foot"],
                         "left_foot.*both feet")):
        data = json.loads(json.dumps(rig))
        edit(data)
        (tmp_path / "r.json").write_text(json.dumps(data))
        with pytest.raises(RigError, match=field):
            load_rig(str(tmp_path / "r.json"))


def test_the_command_refuses_a_hostile_rig_in_one_line(toy_bundle, tmp_path, capsys):  # noqa: F811
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    code = main(["generate", WALK, "--bundle", str(toy_bundle), "-o", str(tmp_path / "x.glb"), "--rig",
                 str(tmp_path / "zero.json")])
    assert "not a regular file" in one_error_line(capsys, code)


# --------------------------------------------------------------------------------------------- stdin

def run_stream(bundle: Path, stdin, *args: str, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    code = "import sys; from mogo_runtime.cli import main; sys.exit(main())"
    return subprocess.run([sys.executable, "-c", code, "stream", WALK, "--bundle", str(bundle), "--follow", *args],
                          stdin=stdin, capture_output=True, timeout=timeout, **kw)


def test_follow_with_stdin_closed_is_one_error(toy_bundle):  # noqa: F811
    p = run_stream(toy_bundle, None, "--seconds", "1", preexec_fn=lambda: os.close(0))
    assert p.returncode == 2 and p.stderr.decode().count("\n") == 1 and b"stdin is closed" in p.stderr, p.stderr


def test_follow_reads_no_line_without_end(toy_bundle):  # noqa: F811
    with open("/dev/zero", "rb") as zero:                      # no newline, ever: once buffered without bound
        p = run_stream(toy_bundle, zero, "--seconds", "30")
    err = p.stderr.decode()
    assert p.returncode == 2 and err.count("\n") == 1 and "stdin: a line longer than" in err, err[-300:]


def test_follow_takes_the_newest_prompt_of_a_flood(toy_bundle, tmp_path):  # noqa: F811
    lines = [f"a person walks forward {i}" for i in range(20_000)]
    (tmp_path / "in.txt").write_text("\n".join(lines) + "\n")
    start = time.perf_counter()
    with open(tmp_path / "in.txt", "rb") as f:
        p = run_stream(toy_bundle, f, "--seconds", "4")
    took = time.perf_counter() - start
    events = [json.loads(line) for line in p.stdout.decode().splitlines() if line.startswith('{"event"')]
    assert p.returncode == 0 and events and events[-1]["text"] == lines[-1], p.stderr[-300:]
    assert len(events) < 50, f"{len(events)} prompts followed: a backlog"
    print(f"\n20,000 prompt lines: {len(events)} followed (the newest each time), {took:.1f} s")


# --------------------------------------------------------------------------------------- the tokenizer

@pytest.mark.parametrize("normalizer", [
    {"type": "Replace", "pattern": {"String": "a"}, "content": "a" * 200_000},
    {"type": "Sequence", "normalizers": [{"type": "Lowercase"}, {"type": "Prepend", "prepend": "x" * 100_000}]},
    {"type": "Sequence", "normalizers": "Lowercase"},
], ids=["replace", "prepend-in-sequence", "sequence-not-a-list"])
def test_a_tokenizer_that_could_explode_is_refused_before_loading(toy_bundle, tmp_path, capsys,  # noqa: F811
                                                                   normalizer):
    b = copy_of(toy_bundle, tmp_path)
    tok = json.loads((b / "tokenizer.json").read_text())
    tok["normalizer"] = normalizer
    (b / "tokenizer.json").write_text(json.dumps(tok))
    rehash(b, "tokenizer.json")
    with pytest.raises(BundleError, match=r"tokenizer.json: normalizer .* is not one this runtime reads"):
        MotionGenerator(b)
    assert "tokenizer.json: normalizer" in one_error_line(capsys, main(["info", str(b)]))


def test_info_reads_the_tokenizer_not_only_its_hash(toy_bundle, tmp_path, capsys):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    (b / "tokenizer.json").write_text('{"not": "a tokenizer"}')
    rehash(b, "tokenizer.json")
    assert "tokenizer.json" in one_error_line(capsys, main(["info", str(b)]))


# -------------------------------------------------------------------------------------- lying graphs

def test_a_step_whose_cache_grows_too_fast_is_refused_at_once(toy_bundle, tmp_path):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    graph_edit("step.onnx", doubled_presents)(b)
    gen = MotionGenerator(b)
    start = time.perf_counter()
    with pytest.raises(BundleError, match=r"step.onnx: returned logits .* and a cache .* the manifest's model says"):
        gen.generate(WALK, seconds=2, seed=0)
    assert time.perf_counter() - start < 5


def test_a_graph_onnxruntime_cannot_run_is_a_bundle_error(toy_bundle, tmp_path, capsys):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    graph_edit("decoder.onnx", failing_reshape)(b)
    with pytest.raises(BundleError, match=r"decoder.onnx: onnxruntime could not run the decoder graph"):
        MotionGenerator(b).generate(WALK, seconds=1, seed=0)
    code = main(["generate", WALK, "--bundle", str(b), "--seconds", "1", "-o", str(tmp_path / "x.npy")])
    assert "could not run the decoder graph" in one_error_line(capsys, code)


def test_onnxruntime_adds_no_lines_to_an_error(toy_bundle, tmp_path):  # noqa: F811
    """A graph onnxruntime warns about while loading (an unused initializer), refused for its metadata: the error
    is the only line (onnxruntime's warning came first, in colour, before)."""
    import onnx

    b = copy_of(toy_bundle, tmp_path)

    def unused_weight_and_wrong_facts(g):
        g.initializer.append(onnx.numpy_helper.from_array(np.zeros(3, np.float32), "never_used"))
    graph_edit("decoder.onnx", unused_weight_and_wrong_facts)(b)
    model = onnx.load(str(b / "decoder.onnx"))
    onnx.helper.set_model_props(model, {"mogo.downsample": "9"})
    onnx.save(model, str(b / "decoder.onnx"))
    rehash(b, "decoder.onnx")
    code = "import sys; from mogo_runtime.cli import main; sys.exit(main())"
    p = subprocess.run([sys.executable, "-c", code, "generate", WALK, "--bundle", str(b), "-o", str(tmp_path / "x.npy")],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and p.stderr.startswith("mogo: error:") and p.stderr.count("\n") == 1, p.stderr
    assert "metadata mogo.downsample is '9'" in p.stderr


def test_the_broken_bundles_of_the_javascript_tests_are_refused_here_too(toy_bundle, portable_toy_bundle,  # noqa: F811
                                                                         tmp_path):
    """js/test/make_broken.py's cases (logits wider or narrower, declared or only at run time, through the portable
    step's IOBinding too; a cache that grows; a graph that fails when run; NaN weights; an exploding tokenizer):
    refused by this runtime as by the JavaScript one, naming the file."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "js" / "test"))
    from make_broken import CASES

    for name, (source, damage) in CASES.items():
        b = tmp_path / name
        shutil.copytree(toy_bundle if source == "toy" else portable_toy_bundle, b)
        damage(b)
        with pytest.raises(BundleError, match=str(b)):
            gen = MotionGenerator(b, variant="fp32" if source == "toy" else "portable")
            gen.generate(WALK, seconds=1, seed=0)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.update(post_processor={"type": "RobertaProcessing"}), "post_processor 'RobertaProcessing'"),
    (lambda t: t.update(added_tokens=[{"id": 0, "content": "[PAD]", "special": True, "lstrip": True}]),
     r"added_tokens\[0\].lstrip is true"),
    (lambda t: t["padding"].update(pad_to_multiple_of=10 ** 6), "padding.pad_to_multiple_of must be in"),
], ids=["post-processor", "added-token-rule", "pad-multiple"])
def test_tokenizers_read_as_the_javascript_runtime_reads_them(toy_bundle, tmp_path, edit, message):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    tok = json.loads((b / "tokenizer.json").read_text())
    edit(tok)
    (b / "tokenizer.json").write_text(json.dumps(tok))
    rehash(b, "tokenizer.json")
    with pytest.raises(BundleError, match=message):
        MotionGenerator(b)


def test_a_model_of_absurd_size_is_refused_before_anything_is_built(toy_bundle, tmp_path):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    m = read_manifest(b)
    m["model"]["n_layers"] = 2 ** 31
    write_manifest(b, m)
    start = time.perf_counter()
    with pytest.raises(BundleError, match=r"field model.n_layers: expected an integer in \[1, 1024\]"):
        MotionGenerator(b)
    assert time.perf_counter() - start < 1


# -------------------------------------------------------------------------------------------- sizes

def test_names_no_file_system_takes_are_refused_with_the_reason(toy_bundle, tmp_path, capsys):  # noqa: F811
    b = copy_of(toy_bundle, tmp_path)
    m = read_manifest(b)
    m["files"]["x" * 300 + ".onnx"] = m["files"]["lookup.onnx"]
    write_manifest(b, m)
    with pytest.raises(BundleError, match="a file name of more than 255 bytes"):
        MotionGenerator(b)
    out = tmp_path / ("y" * 252 + ".bvh")
    code = main(["generate", WALK, "--bundle", str(toy_bundle), "-o", str(out)])
    assert "a file name of more than 255 bytes" in one_error_line(capsys, code)


@pytest.mark.parametrize("edit, message", [
    ({"lexical_weight": [1]}, "tca.lexical_weight: expected a number in"),
    ({"split_margin": {}}, "tca.split_margin: expected a number in"),
    ({"lexical_weight": 1e308}, "tca.lexical_weight: expected a number in"),
    ({"split_margin": -5}, "tca.split_margin: expected a number in"),
])
def test_the_tca_section_is_typed(toy_bundle, tmp_path, edit, message):  # noqa: F811
    b = add_caption_index(toy_bundle, tmp_path / "indexed")
    m = read_manifest(b)
    m["tca"].update(edit)
    write_manifest(b, m)
    with pytest.raises(BundleError, match=message):
        MotionGenerator(b)


def test_a_crowd_is_bounded(portable_toy_bundle):  # noqa: F811
    gen = MotionGenerator(portable_toy_bundle, variant="portable")
    crowd = Crowd(gen, max_characters=3)
    for i in range(3):
        crowd.add(WALK, seed=i)
    with pytest.raises(ValueError, match="this crowd holds at most 3 characters"):
        crowd.add(WALK)
    default = Crowd(gen)
    assert default.max_characters * default.character_bytes <= 0.6 * os.sysconf("SC_PHYS_PAGES") * os.sysconf(
        "SC_PAGE_SIZE") and default.max_characters >= 1
    with pytest.raises(ValueError, match="max_characters"):
        Crowd(gen, max_characters=0)
    # the step cache is reserved up front (address space, used as characters come): more than the system can map
    # is refused at once, naming the bound
    with pytest.raises(MemoryError, match=r"could not reserve the step cache .* max_characters=N"):
        Crowd(gen, max_characters=10 ** 12)


# ------------------------------------------------------------------------------------------- threads

class SlowSteps:
    """A backend whose every step takes `seconds`: time for another thread to switch the prompt mid-step."""

    def __init__(self, backend, seconds: float):
        self.backend, self.seconds, self.dims = backend, seconds, backend.dims

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def step(self, *args):
        time.sleep(self.seconds)
        return self.backend.step(*args)


def test_a_prompt_switch_from_another_thread_lands_at_the_next_token(toy_bundle):  # noqa: F811
    gen = MotionGenerator(toy_bundle)
    walk, jump = gen.backend.encode_text([WALK]), gen.backend.encode_text([JUMP])
    spec, sampling = gen.bundle.manifest.streaming, SamplingConfig()

    def run(switch):
        loop = EndlessLoop(SlowSteps(gen.backend, 0.05), walk, sampling, [3], spec)
        tokens, landed = [loop.step() for _ in range(4)], None
        thread = threading.Thread(target=lambda: tokens.append(loop.step()))
        thread.start()
        time.sleep(0.02)                    # the step is running now
        landed = switch(loop)
        thread.join()
        return tokens + [loop.step() for _ in range(6)], landed
    serial = EndlessLoop(gen.backend, walk, sampling, [3], StreamingSpec(spec.window, spec.refresh))
    want = [serial.step() for _ in range(5)]
    assert serial.set_prompt(jump) == 5
    want += [serial.step() for _ in range(6)]
    got, landed = run(lambda loop: loop.set_prompt(jump))
    assert landed == 5 and all(np.array_equal(a, b) for a, b in zip(want, got))


def test_one_thread_ticks_a_crowd(portable_toy_bundle, monkeypatch):  # noqa: F811
    gen = MotionGenerator(portable_toy_bundle, variant="portable")
    crowd = Crowd(gen)
    crowd.add(WALK, seed=1)
    step = gen.backend.step_in_place
    monkeypatch.setattr(gen.backend, "step_in_place", lambda *a: (time.sleep(0.2), step(*a))[1])
    thread = threading.Thread(target=crowd.tick)
    thread.start()
    time.sleep(0.05)
    with pytest.raises(RuntimeError, match=r"Crowd.tick\(\) is running in another thread"):
        crowd.tick()
    thread.join()


def test_closed_streams_and_removed_characters_follow_no_prompt(toy_bundle, portable_toy_bundle):  # noqa: F811
    s = MotionGenerator(toy_bundle).stream(WALK, seed=0, chunk=4)
    next(s)
    s.close()
    with pytest.raises(ValueError, match="this stream is closed"):
        s.set_prompt(JUMP)
    assert list(s) == []            # the frames decoded and not read are dropped: it hands out no more
    crowd = Crowd(MotionGenerator(portable_toy_bundle, variant="portable"))
    c = crowd.add(WALK)
    crowd.remove(c)
    with pytest.raises(ValueError, match="not in this crowd"):
        c.set_prompt(JUMP)


# ------------------------------------------------------------------------------------------ messages

def test_error_lines_stay_one_short_line(toy_bundle, tmp_path, capsys):  # noqa: F811
    code = main(["generate", WALK, "--bundle", str(toy_bundle), "-o", str(tmp_path / "evil\nname.fbx")])
    assert "evil\\nname.fbx" in one_error_line(capsys, code)
    code = main(["generate", " " * 10_000, "--bundle", str(toy_bundle), "-o", str(tmp_path / "x.npy")])
    assert len(one_error_line(capsys, code)) < 300
    gen = MotionGenerator(toy_bundle)
    with pytest.raises(ValueError) as e:
        gen.generate([(WALK, 0.0)] + [(JUMP, float(i)) for i in range(1, 10_000)], seconds=5)
    assert len(str(e.value)) < 400
    with pytest.raises(ValueError, match="a timeline start: it must be between"):
        gen.generate([(WALK, 0.0), (JUMP, 1e6)], seconds=5)
