"""Hostile input to the runtime's public API and the `mogo` command: huge prompts and numbers, text that is not
Unicode, absurd thread and chunk counts, decompression bombs and damaged caption indexes. Each ends in a clear
ValueError / BundleError (or one `mogo: error:` line and exit status 2), quickly and without a large allocation.

Runs with torch blocked, on the toy bundle.
"""
import io
import json
import shutil
import subprocess
import sys
import time
import tracemalloc
import warnings
import zipfile
import zlib
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import MotionGenerator, SamplingConfig
from mogo_runtime.bundle.folder import sha256_file
from mogo_runtime.bundle.sections import BundleError
from mogo_runtime.cli import main
from mogo_runtime.tca import CaptionIndex, OfflineAligner
from mogo_runtime.tca import index as index_module
from mogo_runtime.tca.offline import MAX_CLAUSE_CHARS, MAX_CLAUSES, MAX_SPLITS
from mogo_runtime.text import MAX_PROMPT_CHARS, session_options

TEXT = "a person walks forward"
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def gen(toy_bundle) -> MotionGenerator:  # noqa: F811
    return MotionGenerator(toy_bundle)


def fits(unit: str, n: int) -> str:
    return (unit * (n // len(unit) + 1))[:n]


# ------------------------------------------------------------------------------------------- prompts

@pytest.mark.parametrize("align", [False, True])
def test_prompts_over_the_limit_are_refused_at_once(gen, align):
    """A 1 MB prompt took 0.9 s (10 MB of CJK: 36 s and 5 GB) to be cut at the encoder's 256 tokens; with
    align=True a 100,000-character one took 5 s and a 1 MB one 53 s."""
    for n, unit in ((100_000, "a person walks forward and then jumps twice, "), (1_000_000, "走")):
        text = fits(unit, n)
        start = time.perf_counter()
        with pytest.raises(ValueError, match=f"prompt 0 has {n:,} characters; a prompt may have at most 10,000"):
            gen.generate(text, seconds=1, align=align)
        with pytest.raises(ValueError, match="at most 10,000"):
            gen.stream(text, align=align)
        with pytest.raises(ValueError, match="at most 10,000"):
            gen.generate([TEXT, text], seconds=1, align=align)
        with pytest.raises(ValueError, match="at most 10,000"):
            gen.stream(TEXT, seconds=1).set_prompt(text, align=align)
        assert time.perf_counter() - start < 1.0
    gen.generate(fits("walk ", MAX_PROMPT_CHARS), seconds=0.2, align=align)     # the limit itself is allowed


class CountingEncoder:
    """A fake text session: a fixed random vector per word, summed; counts the rows and characters it embeds."""

    def __init__(self, dim: int = 32):
        self.dim, self.rows, self.chars = dim, 0, 0

    def encode(self, texts):
        self.rows += len(texts)
        self.chars += sum(map(len, texts))
        out = []
        for t in texts:
            v = sum((np.random.default_rng(zlib.crc32(w.encode())).standard_normal(self.dim)
                     for w in t.lower().strip(".").split()), np.full(self.dim, 1e-3))
            out.append(v / np.linalg.norm(v))
        return np.array(out, np.float32)


CAPTIONS = ["a person jumps.", "a person waves.", "a person kicks.", "a person punches.", "a person walks forward.",
            "a person turns left."]


@pytest.mark.parametrize("prompt", [
    fits("jump and wave and ", MAX_PROMPT_CHARS),                             # one run-on clause
    ", then ".join([fits("walks forward and turns left and ", 900)] * 4),     # four of them
    fits("a person walks forward and then jumps twice, ", MAX_PROMPT_CHARS),   # 222 clauses
    fits("👋🏃", MAX_PROMPT_CHARS),                                              # words longer than the text
])
def test_alignment_work_and_output_are_bounded_under_the_limit(prompt):
    """Within the limit: at most 3 x MAX_SPLITS + MAX_CLAUSES encoder rows of at most MAX_CLAUSE_CHARS (plus the
    sentence around it) each, an aligned text the encoder accepts, and a warning saying what was cut."""
    session = CountingEncoder()
    index = CaptionIndex(CAPTIONS, session.encode(CAPTIONS), None, "counting")
    for aligner in (OfflineAligner(index=index, text_session=session, split_margin=0.0), OfflineAligner()):
        raw = aligner.normalizer.normalize(prompt)     # the index's vocabulary drops words, so it may need no cut
        over = len(raw) > MAX_CLAUSES or max(map(len, raw)) > MAX_CLAUSE_CHARS
        assert over or aligner.has_index
        session.rows = session.chars = 0
        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out = aligner.align(prompt)
        assert time.perf_counter() - start < 2.0
        assert [str(w.message).startswith("align: the prompt is cut: ") for w in caught] == ([True] if over else [])
        assert session.rows <= 3 * MAX_SPLITS + MAX_CLAUSES
        assert session.chars <= session.rows * (MAX_CLAUSE_CHARS + len("a person ."))
        assert len(out.details["clauses"]) <= MAX_CLAUSES
        assert all(len(c) <= MAX_CLAUSE_CHARS for c in out.details["clauses"])
        assert 0 < len(out.text) <= MAX_PROMPT_CHARS


def test_short_prompts_are_aligned_without_a_cut():
    session = CountingEncoder()
    index = CaptionIndex(CAPTIONS, session.encode(CAPTIONS), None, "counting")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = OfflineAligner(index=index, text_session=session).align("jump, then wave, then kick and punch")
    assert out.method == "nearest" and len(out.details["clauses"]) >= 3


@pytest.mark.parametrize("text", ["a person \ud800 walks", "\udcff\udcfe", "a person walks \udfff"])
def test_prompts_that_are_not_unicode_text_are_refused(gen, text):
    """A lone surrogate (what Python makes of argv bytes that are not UTF-8) reached the tokenizer, which raised
    "TextEncodeInput must be Union[...]"."""
    for call in (lambda: gen.generate(text, seconds=1), lambda: gen.stream(text),
                 lambda: gen.generate(text, seconds=1, align=True), lambda: gen.backend.encode_text([text])):
        with pytest.raises(ValueError, match="prompt 0 is not valid Unicode text: character .* lone surrogate"):
            call()


# ------------------------------------------------------------------------------------------- numbers

NUMPY_SCALARS = [np.float16, np.float32, np.float64, np.int8, np.int32, np.int64, np.uint8, np.uint64]


@pytest.mark.parametrize("kind", NUMPY_SCALARS + [Fraction])
def test_numpy_and_other_real_scalars_are_numbers(gen, kind):
    cfg = SamplingConfig(temperature=kind(1), top_p=kind(1), guidance=kind(2))
    assert (cfg.temperature, cfg.top_p, cfg.guidance) == (1.0, 1.0, 2.0)
    assert all(type(v) is float for v in (cfg.temperature, cfg.top_p, cfg.guidance))
    assert gen.tokens_for(kind(2)) == gen.tokens_for(2)
    if kind is not Fraction and np.issubdtype(kind, np.integer):
        assert SamplingConfig(top_k=kind(3)).top_k == 3 and type(SamplingConfig(top_k=kind(3)).top_k) is int
        m = gen.generate(TEXT, seconds=kind(1), seed=kind(3), sampling=SamplingConfig(top_k=kind(3)))
        assert np.array_equal(m.tokens, gen.generate(TEXT, seconds=1, seed=3, sampling=SamplingConfig(top_k=3)).tokens)


@pytest.mark.parametrize("value", [1e308, 10 ** 400, -10 ** 400, float("inf"), float("nan"), np.float64("nan"),
                                   np.float32("inf"), Fraction(10 ** 400)])
def test_huge_and_non_finite_numbers_are_refused_with_the_range(gen, value):
    """seconds=1e308 raised OverflowError; so did an int too large for a float anywhere a number was read."""
    with pytest.raises(ValueError, match=r"seconds must be between 0\.2 and 3600 seconds"):
        gen.generate(TEXT, seconds=value)
    with pytest.raises(ValueError, match=r"temperature must be in \[0, 100\] \(0 = greedy\), got "):
        SamplingConfig(temperature=value)
    with pytest.raises(ValueError, match=r"guidance must be in \[0, 100\]"):
        SamplingConfig(guidance=value)
    with pytest.raises(ValueError, match=r"top_p must be in \(0, 1\]"):
        SamplingConfig(top_p=value)


@pytest.mark.parametrize("value", [True, False, np.bool_(True), "1", None, [1], 1j, np.array(1.0)])
def test_bools_and_non_numbers_are_refused(gen, value):
    if value is not None:
        with pytest.raises(ValueError, match="seconds must be a number between"):
            gen.generate(TEXT, seconds=value)
    with pytest.raises(ValueError, match="temperature must be a number in"):
        SamplingConfig(temperature=value)
    if not isinstance(value, list):     # a list is one seed per prompt
        with pytest.raises(ValueError, match="seed must be an int"):
            gen.generate(TEXT, seconds=1, seed=value)
    if value is not None:
        with pytest.raises(ValueError, match="top_k must be an int"):
            SamplingConfig(top_k=value)


def test_an_int_too_long_to_print_is_described_not_printed():
    with pytest.raises(ValueError, match="top_k must be an int >= 1 .*got an int of 33220 bits"):
        SamplingConfig(top_k=-10 ** 10000)
    with pytest.raises(ValueError, match="temperature must be in .*got an int of 33220 bits"):
        SamplingConfig(temperature=10 ** 10000)


@pytest.mark.parametrize("threads", [0, -1, 65, 10 ** 6, 10 ** 30, True, 1.0, "2", np.float64(2)])
def test_thread_counts_are_bounded_before_onnxruntime_sees_them(toy_bundle, threads):  # noqa: F811
    """threads=10**6 ended in SIGSEGV (MotionGenerator) or a hang (TextEncoderSession) inside onnxruntime."""
    with pytest.raises(ValueError, match=r"threads must be an int in \[1, 64\], got "):
        MotionGenerator(toy_bundle, threads=threads)
    with pytest.raises(ValueError, match=r"threads must be an int in \[1, 64\]"):
        session_options(threads)


def test_numpy_thread_counts_are_accepted(toy_bundle):  # noqa: F811
    assert session_options(np.int64(2)).intra_op_num_threads == 2
    assert MotionGenerator(toy_bundle, threads=np.int32(2)).generate(TEXT, seconds=0.2).num_frames == 4


@pytest.mark.parametrize("chunk", [0, 10 ** 9, 1025, True, 2.0])
def test_stream_chunks_are_bounded(gen, chunk):
    """chunk=10**9 raised MemoryError (the decoding window is allocated up front)."""
    with pytest.raises(ValueError, match=r"chunk must be an int in \[1, 1024\], got "):
        gen.stream(TEXT, chunk=chunk)


@pytest.mark.parametrize("variant", ["", " ", "FP32", "fp32 ", None, 0])
def test_unknown_variants_are_refused(toy_bundle, variant):  # noqa: F811
    with pytest.raises(ValueError, match="variant"):
        MotionGenerator(toy_bundle, variant=variant)


# ------------------------------------------------------------------------------------------- caption index

def npz(path: Path, members: dict, level: int = 6) -> Path:
    """Write a zip of .npy members: an array, or (header dict, data bytes or (byte, count)) for a lying one."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=level) as zf:
        for name, value in members.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                if isinstance(value, np.ndarray):
                    np.lib.format.write_array(f, value, allow_pickle=True)
                    continue
                header, data = value
                np.lib.format.write_array_header_1_0(f, header)
                if isinstance(data, bytes):
                    f.write(data)
                    continue
                chunk, left = bytes(16 * 2 ** 20), data
                while left:
                    f.write(chunk[:min(left, len(chunk))])
                    left -= min(left, len(chunk))
    return path


def good_members(n: int = 3, dim: int = 8) -> dict:
    rows = np.ones((n, dim), np.int8)
    return {"format": np.array("mogo-caption-index"), "version": np.array(1, np.int64), "encoder": np.array("toy"),
            "captions": np.array([f"a person jumps {i}." for i in range(n)]), "embeddings": rows,
            "scales": np.ones(n, np.float32), "labels": np.array(["jump"] * n)}


def header(shape, descr="|i1") -> dict:
    return {"descr": descr, "fortran_order": False, "shape": shape}


BAD_INDEXES = {
    "the bomb": ({"embeddings": (header((10 ** 6, 384)), 10 ** 6 * 384)},
                 "bytes decompressed; at most 268,435,456 are read"),
    "a lying header": ({"embeddings": (header((3, 4096)), b"\0" * 1000)},
                       "its header says 12,288 bytes of data, the member holds 1,000"),
    "too many rows": ({"captions": (header((600_000,), "<U1"), 4 * 600_000)}, "N must be in [1, 500,000]"),
    "too wide": ({"embeddings": (header((3, 5000)), 3 * 5000)}, "D must be in [1, 4,096]"),
    "too many values": ({"captions": np.array(["a"] * 20_000), "labels": np.array(["a"] * 20_000),
                         "scales": np.ones(20_000, np.float32), "embeddings": (header((20_000, 4096)), 20_000 * 4096)},
                        "has 81,920,000 values; at most 67,108,864 are read"),
    "an object array": ({"captions": np.array(["a", None], object)}, "has dtype |O; expected text"),
    "a pickle": ({"captions": (header((3,), "|O"), b"\x80\x04N.")}, "has dtype |O"),
    "long strings": ({"captions": np.array(["x" * 1001] * 3)}, "text of at most 1000 characters"),
    "a float version": ({"version": np.array(1.0)}, "'version' has dtype <f8; expected an integer"),
    "1-d embeddings": ({"embeddings": np.ones(24, np.int8)}, "has shape (24,), expected 2 dimension(s)"),
    "counts that differ": ({"scales": np.ones(4, np.float32)}, "other arrays have N = 3"),
    "no captions": ({"captions": np.array([], "<U4"), "labels": np.array([], "<U4"), "scales": np.ones(0, np.float32),
                     "embeddings": np.ones((0, 8), np.int8)}, "N must be in [1, 500,000]"),
    "a bad magic": ({"embeddings": (header((3, 8)), b"")}, None),
}


@pytest.mark.parametrize("case", BAD_INDEXES)
def test_bad_caption_indexes_are_refused_before_they_are_read(tmp_path, case):
    """np.load decompresses a whole member: a 382 KB file of zeros took 8.9 s and 3.4 GB before this."""
    members, message = BAD_INDEXES[case]
    if case == "a bad magic":     # the member's bytes do not start with \x93NUMPY
        path = tmp_path / "captions.npz"
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("embeddings.npy", b"PK not an npy header at all")
            for name, value in good_members().items():
                if name != "embeddings":
                    zf.writestr(f"{name}.npy", _npy_bytes(value))
        message = "not a readable caption index"
    else:
        path = npz(tmp_path / "captions.npz", {**good_members(), **members}, level=1)
    tracemalloc.start()
    try:
        start = time.perf_counter()
        with pytest.raises(BundleError) as e:
            CaptionIndex.load(path)
        took, peak = time.perf_counter() - start, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert str(e.value).startswith(f"{path}: ") and message in str(e.value), str(e.value)
    assert took < 0.5 and peak < 2 * 2 ** 20


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


@pytest.mark.parametrize("damage", ["not a zip", "truncated", "flipped bytes", "empty"])
def test_damaged_caption_indexes_are_bundle_errors(tmp_path, damage):
    """BadZipFile, zlib.error, EOFError and numpy's ValueError all came out as they were."""
    good = npz(tmp_path / "good.npz", good_members())
    assert len(CaptionIndex.load(good)) == 3
    data = good.read_bytes()
    data = {"not a zip": b"not a zip", "truncated": data[:len(data) // 2], "empty": b"",
            "flipped bytes": data[:60] + bytes(b ^ 0xFF for b in data[60:200]) + data[200:]}[damage]
    path = tmp_path / "captions.npz"
    path.write_bytes(data)
    with pytest.raises(BundleError, match=f"^{path}: "):
        CaptionIndex.load(path)


def test_a_bundle_with_a_caption_bomb_fails_with_a_bundle_error(toy_bundle, tmp_path):  # noqa: F811
    """The bomb reached through the public API: generate(align=True) reads the bundle's caption index."""
    dst = shutil.copytree(toy_bundle, tmp_path / "bundle")
    members = {**good_members(), "embeddings": (header((10 ** 6, 384)), 10 ** 6 * 384)}
    npz(dst / "captions.npz", members, level=1)
    m = json.loads((dst / "manifest.json").read_text())
    m["tca"] = {"file": "captions.npz", "count": 3, "dim": 8, "dtype": "int8", "encoder": "toy", "labels": True}
    m["files"]["captions.npz"] = {"bytes": (dst / "captions.npz").stat().st_size,
                                  "sha256": sha256_file(dst / "captions.npz")}
    (dst / "manifest.json").write_text(json.dumps(m, indent=2))
    gen = MotionGenerator(dst)
    tracemalloc.start()
    try:
        with pytest.raises(BundleError, match=f"^{dst / 'captions.npz'}: caption index arrays of [0-9,]+ bytes "
                                              f"decompressed; at most 268,435,456 are read"):
            gen.generate(TEXT, seconds=1, align=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2 ** 20
    assert gen.generate(TEXT, seconds=1).num_frames == 20          # without align the index is never read


def test_index_bounds_are_what_the_docs_say():
    doc = " ".join((ROOT / "docs" / "tca.md").read_text().split())
    assert (index_module.MAX_CAPTIONS, index_module.MAX_DIM, index_module.MAX_TEXT) == (500_000, 4096, 1000)
    assert (index_module.MAX_VALUES, index_module.MAX_BYTES) == (2 ** 26, 256 * 2 ** 20)
    for words in ("at most 500,000 captions", "4,096 values a row", "2^26 embedding values",
                  "1,000 characters a string", "256 MiB decompressed", "at most 10,000 characters", "first 8 clauses",
                  "500 characters each"):
        assert words in doc, words
    assert (MAX_PROMPT_CHARS, MAX_CLAUSES, MAX_CLAUSE_CHARS, MAX_SPLITS) == (10_000, 8, 500, 8)


# ------------------------------------------------------------------------------------------- the command

def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


BAD_COMMANDS = [
    (["generate", "\udcff\udcfe"], "prompt 0 is not valid Unicode text"),          # argv bytes that are not UTF-8
    (["stream", "a person \udcff walks"], "prompt 0 is not valid Unicode text"),
    (["generate", fits("walk ", 100_000)], "prompt 0 has 100,000 characters"),
    (["generate", fits("walk ", 20_000), "--align"], "prompt 0 has 20,000 characters"),
    (["generate", TEXT, "--seconds", "1e308"], "seconds must be between"),
    (["generate", TEXT, "--seconds", "1e400"], "seconds must be between"),
    (["generate", TEXT, "--seconds", "nan"], "seconds must be between"),
    (["generate", TEXT, "--seconds=-inf"], "seconds must be between"),
    (["stream", TEXT, "--seconds", "inf"], "seconds must be between"),
    (["generate", TEXT, "--threads", "1000000"], "threads must be an int in [1, 64], got 1000000"),
    (["stream", TEXT, "--threads", "0"], "threads must be an int in [1, 64], got 0"),
    (["generate", TEXT, "--temperature", "inf"], "temperature must be in [0, 100]"),
    (["generate", TEXT, "--temperature", "nan"], "temperature must be in [0, 100]"),
    (["generate", TEXT, "--top-p", "nan"], "top_p must be in (0, 1]"),
    (["generate", TEXT, "--guidance", "1e400"], "guidance must be in [0, 100]"),
    (["generate", TEXT, "--seed", "9" * 30], "seeds must be ints in [0, 2**63)"),
    (["generate", TEXT, "--seed", "9" * 5000], "invalid int value"),
    (["generate", TEXT, "--top-k", "-1"], "top_k must be an int >= 1"),
    (["generate", TEXT, "--variant", ""], "variant must be a variant name"),
    (["generate", TEXT, "--rig", "\udcff"], "unknown rig"),
]


@pytest.mark.parametrize("argv, needle", BAD_COMMANDS, ids=[f"{i}-{a[0]}-{a[-1][:12]!r}" for i, (a, _) in
                                                            enumerate(BAD_COMMANDS)])
def test_bad_input_ends_in_one_error_line(capsys, tmp_path, toy_bundle, argv, needle):  # noqa: F811
    out = tmp_path / "x.npy" if "--rig" not in argv else tmp_path / "x.bvh"
    extra = ["-o", out] if argv[0] == "generate" else []
    code, stdout, err = run_cli(capsys, *argv, "--bundle", toy_bundle, *extra)
    assert code == 2 and stdout == "", err
    assert err.startswith("mogo: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert needle in err, err
    assert not out.exists()


def test_a_prompt_line_that_is_not_utf8_ends_a_follow_stream(capsys, monkeypatch, toy_bundle):  # noqa: F811
    """A strict stdin decoder killed the reader thread with a traceback and the stream went on without prompts."""
    stdin = io.TextIOWrapper(io.BytesIO(b"a person jumps \xff\xfe\n"), encoding="utf-8", errors="strict")
    monkeypatch.setattr("sys.stdin", stdin)
    code = main(["stream", TEXT, "--bundle", str(toy_bundle), "--seconds", "4", "--follow"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("mogo: error: stdin: prompt 0 is not valid Unicode text: character 15"), err


def test_real_argv_bytes_that_are_not_utf8(tmp_path, toy_bundle):  # noqa: F811
    """The path the probe took: bytes in argv, decoded by Python with surrogateescape."""
    code = "import sys; from mogo_runtime.cli import main; sys.exit(main())"
    out = tmp_path / "x.npy"
    r = subprocess.run([sys.executable, "-c", code, "generate", b"\xff\xfe", "-o", str(out), "--bundle",
                        str(toy_bundle)], capture_output=True, timeout=60)
    err = r.stderr.decode("utf-8", "backslashreplace")
    assert r.returncode == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("mogo: error: prompt 0 is not valid Unicode text: character 0 is a lone surrogate"), err
    assert not out.exists()
