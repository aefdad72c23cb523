"""Text condition alignment (mogo_runtime.tca): wording, clause splitting, retrieval, the chat rewriter, integration.

Runs with torch blocked. Retrieval uses a tiny index built here with numpy and a bag-of-words fake text session;
the chat rewriter talks to a local http.server started and stopped by the tests.
"""
import hashlib
import json
import shutil
import subprocess
import sys
import threading
import time
import warnings
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest
from toy_bundle import toy_bundle  # noqa: F401  (a fixture)

from mogo_runtime import Bundle, MotionGenerator
from mogo_runtime.bundle.folder import sha256_file
from mogo_runtime.cli import main
from mogo_runtime.tca import (AlignedPrompt, Aligner, CaptionIndex, OfflineAligner, WordingNormalizer, apply_alignment,
                              quantize_rows, sentence, strip_subject)
from mogo_runtime.tca.offline import MAX_SPLITS
from mogo_rewriter import ChatRewriter
from mogo_runtime.text import TextEncoderSession

# ------------------------------------------------------------------------------------------- wording


@pytest.mark.parametrize("raw, clauses", [
    ("yo make the dude do a lil hop on the spot", ["hops in place"]),
    ("guy starts jogging real quick", ["jogs quickly"]),
    ("The man is walking forwards and then he sits down", ["walks forward", "sits down"]),
    ("can you have him wave with his left hand please 🙏", ["waves with his left hand"]),
    ("he waves after he jumps twice", ["jumps twice", "waves"]),                 # "X after Y": Y first
    ("jump, then wave; finally sit down", ["jumps", "waves", "sits down"]),
    ("run forward. after that turn around", ["runs forward", "turns around"]),
    ("kick before you punch", ["kicks", "punches"]),
    ("a person walks forward slowly.", ["walks forward slowly"]),               # already in style: unchanged
    ("bro just chillin lol", ["stands still"]),
    ("do 3 squats", ["squats three times"]),
    ("make her throw some punches", ["punches"]),
    ("👋", ["waves"]),                                                          # an emoji alone is the action
    ("SHE JUMPED 2x!!!", ["jumps twice"]),
    ("back up slowly", ["walks backward slowly"]),
    ("", []), ("lol ok", []),
    # actions of their own since the 67 families: not rewritten into older ones (jump in place, punch, both arms)
    ("do some jumping jacks", ["does jumping jacks"]), ("a man is doing 5 jumping jacks", ["does five jumping jacks"]),
    ("star jumps for warm-up", ["does star jumps for warm up"]),
    ("he pumps his fists", ["pumps his fists"]), ("reach up to the top shelf", ["reaches up to the top shelf"]),
])
def test_wording_is_normalised_and_split_in_order(raw, clauses):
    assert WordingNormalizer().normalize(raw) == clauses


def test_sentence_and_subject_helpers():
    assert sentence(["walks forward", "jumps"]) == "a person walks forward and then jumps."
    assert sentence([]) == ""
    assert strip_subject("A man walks forward slowly.") == "walks forward slowly"
    assert strip_subject("someone first kicks and then bows.") == "kicks and then bows"


def test_vocabulary_maps_synonyms_and_drops_unseen_objects():
    vocab = {"a", "person", "walks", "forward", "jumps", "in", "place", "kicks", "with", "his", "right", "leg",
             "sits", "down", "on", "chair", "runs"}
    n = WordingNormalizer(vocab)
    assert n.normalize("the dude hops on the spot") == ["jumps in place"]        # "hops" unknown -> "jumps"
    assert n.normalize("kick the ball with his right leg") == ["kicks with his right leg"]
    assert n.normalize("he sprints to the store") == ["runs"]
    assert n.normalize("strolls forward") == ["walks forward"]


# ------------------------------------------------------------------------------------------- retrieval

CAPTIONS = [("a man walks forward slowly.", "walk_forward"), ("a person jumps in place twice.", "jump_in_place"),
            ("a woman waves with her left hand.", "wave_left_hand"),
            ("a woman waves with her right hand.", "wave_right_hand"),
            ("a person sits down on a chair.", "sit_down"), ("someone kicks with his right leg.", "kick_right"),
            ("a person walks backward.", "walk_backward"), ("a person claps his hands.", "clap"),
            ("a man walks forward and then sits down.", "seq:walk_forward+sit_down")]
DIM = 48


class BagOfWords:
    """A fake text session: the mean of fixed random word vectors (content words only), L2-normalised."""
    STOP = {"a", "an", "the", "person", "man", "woman", "someone", "his", "her", "their", "with"}

    def __init__(self):
        self.calls = self.rows = 0

    def vector(self, word: str) -> np.ndarray:
        seed = int(hashlib.sha1(word.encode()).hexdigest()[:8], 16)
        return np.random.default_rng(seed).standard_normal(DIM)

    def encode(self, texts):
        self.calls += 1
        self.rows += len(texts)
        out = []
        for t in texts:
            words = [w.strip(".,") for w in t.lower().split() if w.strip(".,") not in self.STOP]
            v = sum((self.vector(w) for w in words), np.zeros(DIM)) + 1e-3
            out.append(v / np.linalg.norm(v))
        return np.array(out, np.float32)


@pytest.fixture(scope="module")
def index() -> CaptionIndex:
    texts = [c for c, _ in CAPTIONS]
    return CaptionIndex(texts, BagOfWords().encode(texts), [lb for _, lb in CAPTIONS], "bag-of-words")


@pytest.mark.parametrize("raw, caption", [
    ("yo make the dude do a lil hop on the spot", "a person jumps in place twice."),
    ("guy waves w/ his left hand", "a woman waves with her left hand."),
    ("the chick is waving her right hand at a friend", "a woman waves with her right hand."),
    ("have a seat", "a person sits down on a chair."),
    ("backpedal", "a person walks backward."),
    ("applause!!", "a person claps his hands."),
])
def test_retrieval_finds_the_right_training_caption(index, raw, caption):
    aligned = OfflineAligner(index=index, text_session=BagOfWords()).align(raw)
    assert aligned.method == "nearest"
    assert aligned.text == sentence([strip_subject(caption)])
    assert aligned.details["neighbours"][0][0][0] == caption


def test_compound_requests_become_ordered_captions(index):
    aligner = OfflineAligner(index=index, text_session=BagOfWords())
    a = aligner.align("take a seat after u hop around a bit")
    assert a.text == "a person jumps in place twice and then sits down on a chair."
    assert len(a.details["clauses"]) == 2
    # single clauses match single-action captions only, never a sequence caption
    assert all(n[0][0] != CAPTIONS[-1][0] for n in a.details["neighbours"])


def test_bare_and_splits_only_where_retrieval_prefers_parts(index):
    aligner = OfflineAligner(index=index, text_session=BagOfWords(), split_margin=0.0)
    assert aligner.align("clap and kick with the right leg").details["clauses"] == ["claps", "kicks with the right leg"]


def test_a_run_on_clause_tries_a_bounded_number_of_splits(index):
    """Each bare "and" tried embeds the clause's parts: all of them made alignment quadratic in the length."""
    session = BagOfWords()
    aligner = OfflineAligner(index=index, text_session=session, split_margin=0.0)
    for repeats in (2, 50, 500):
        session.rows = 0
        with pytest.warns(UserWarning, match="prompt is cut") if repeats > 2 else warnings.catch_warnings():
            aligner.align("clap and kick " * repeats + "and clap")    # past 500 characters a clause is cut
        assert session.rows <= 3 * MAX_SPLITS + 2          # the tries, then one row per clause


def test_apply_alignment_encodes_the_aligned_texts(index):
    session = BagOfWords()
    prompts = OfflineAligner(index=index, text_session=session).align_batch(["backpedal", "lol ok"])
    emb = apply_alignment(prompts, session.encode)
    assert emb.dtype == np.float32 and np.array_equal(emb, session.encode(["a person walks backward.", "lol ok"]))
    with pytest.raises(TypeError):      # the removed `embedding` argument: fails loudly, not as method=None
        AlignedPrompt("a person jumps.", None, "custom")


def test_unknown_prompts_and_aligning_without_an_index(index):
    none = OfflineAligner(index=index, text_session=BagOfWords()).align("lol ok")
    assert (none.text, none.method) == ("lol ok", "none")
    with warnings.catch_warnings():
        warnings.simplefilter("error")                    # no bundle, so no "bundle without an index" warning
        plain = OfflineAligner().align("guy starts jogging")
    assert (plain.text, plain.method) == ("a person jogs.", "normalize")   # no caption vocabulary: jogs stays


def test_the_offline_path_never_loads_the_rewriter():
    """mogo_runtime never imports mogo_rewriter (a device build leaves it out) nor urllib; the rewriter loads
    urllib only on its first request."""
    code = """if True:
        import json, sys
        import mogo_runtime, mogo_runtime.cli, mogo_runtime.generator, mogo_runtime.tca as tca
        seen = lambda: sorted(m for m in sys.modules if m.startswith("mogo_rewriter") or m == "urllib.request")
        steps = [seen()]
        import mogo_rewriter
        steps.append(seen())
        print(json.dumps(steps))"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    runtime_only, with_rewriter = json.loads(out)
    assert runtime_only == [] and with_rewriter == ["mogo_rewriter"]


def test_index_round_trips_int8_and_float16(tmp_path, index):
    for dtype, tol in (("int8", 2e-2), ("float16", 1e-3)):
        facts = index.save(tmp_path / f"c-{dtype}.npz", dtype)
        assert facts == {"file": f"c-{dtype}.npz", "count": len(CAPTIONS), "dim": DIM, "dtype": dtype,
                         "encoder": "bag-of-words", "labels": True}
        back = CaptionIndex.load(tmp_path / f"c-{dtype}.npz")
        assert back.captions == index.captions and back.labels == index.labels and back.dtype == dtype
        cos = (back.embeddings * index.embeddings).sum(1)
        assert cos.min() > 0.999 and np.abs(back.embeddings - index.embeddings).max() < tol
        np.load(tmp_path / f"c-{dtype}.npz", allow_pickle=False)            # no pickled objects inside
    q, scale = quantize_rows(np.array([[0.5, -1.0, 0.0]]))
    assert q.dtype == np.int8 and q.tolist() == [[64, -127, 0]] and scale.tolist() == pytest.approx([1 / 127])
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="caption index"):
        CaptionIndex.load(tmp_path / "bad.npz")


# ------------------------------------------------------------------------------------------- chat rewriter

class _Handler(BaseHTTPRequestHandler):
    mode = "ok"
    seen: list = []

    def log_message(self, *args):
        pass

    def do_POST(self):
        body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
        type(self).seen.append({"path": self.path, "auth": self.headers.get("Authorization"), "body": body})
        mode = type(self).mode
        if mode == "sleep":
            time.sleep(1.5)
        if mode == "500":
            self.send_response(500)
            self.end_headers()
            self.wfile.write(b"internal error")
            return
        reply = {"choices": [{"message": {"role": "assistant",
                                          "content": "A person jumps in place twice.\n(rewritten)"}}]}
        data = {"ok": json.dumps(reply).encode(), "sleep": json.dumps(reply).encode(),
                "garbage": b"{not json", "shape": json.dumps({"choices": []}).encode(),
                "empty": json.dumps({"choices": [{"message": {"content": "   "}}]}).encode()}[mode]
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)


@pytest.fixture
def server():
    _Handler.mode, _Handler.seen = "ok", []
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.daemon_threads = True                      # a handler still sleeping does not hold up the teardown
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}", _Handler
    finally:
        httpd.shutdown()
        httpd.server_close()
        thread.join(5)


def test_rewriter_success_sends_style_prompt_and_key_from_env(server, index, monkeypatch):
    url, handler = server
    monkeypatch.setenv("MY_TCA_KEY", "sekret-123")
    fallback = OfflineAligner(index=index, text_session=BagOfWords())
    rw = ChatRewriter(url + "/v1", "tiny-llm", api_key_env="MY_TCA_KEY", timeout=2, fallback=fallback)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                                     # success: no warning at all
        out = rw.align("yo make the dude do a lil hop")
    assert (out.text, out.method) == ("a person jumps in place twice.", "chat")
    req = handler.seen[0]
    assert req["path"] == "/v1/chat/completions" and req["auth"] == "Bearer sekret-123"
    assert req["body"]["model"] == "tiny-llm"
    system, user = req["body"]["messages"]
    assert user == {"role": "user", "content": "yo make the dude do a lil hop"}
    assert "a person" in system["content"] and "25 words" in system["content"] and "unchanged" in system["content"]
    assert sum(line.startswith("- a person ") for line in system["content"].splitlines()) >= 5  # index examples


def test_rewriter_without_key_sends_no_authorization(server, monkeypatch):
    url, handler = server
    monkeypatch.delenv("MOGO_TCA_API_KEY", raising=False)
    assert ChatRewriter(url, "m").align("jump").method == "chat"
    assert handler.seen[0]["auth"] is None


@pytest.mark.parametrize("mode, reason", [("sleep", "no answer within"), ("500", "HTTP 500"),
                                          ("garbage", "malformed reply"), ("shape", "malformed reply"),
                                          ("empty", "empty reply")])
def test_rewriter_failures_fall_back_to_offline_with_a_warning(server, index, mode, reason):
    url, handler = server
    handler.mode = mode
    fallback = OfflineAligner(index=index, text_session=BagOfWords())
    rw = ChatRewriter(url + "/v1/chat/completions", "m", timeout=0.5, fallback=fallback)
    t0 = time.perf_counter()
    with pytest.warns(UserWarning, match=reason):
        out = rw.align("yo make the dude do a lil hop on the spot")
    assert time.perf_counter() - t0 < 1.4                                   # the timeout, not the server's sleep
    assert out.method == "nearest" and out.text == "a person jumps in place twice."
    assert reason in out.details["fallback_reason"]


def test_rewriter_unreachable_falls_back(index):
    with pytest.warns(UserWarning, match="cannot reach|connection failed"):
        out = ChatRewriter("http://127.0.0.1:9", "m", timeout=1).align("guy starts jogging")
    assert out.text == "a person jogs." and out.method == "normalize"


def test_rewriter_checks_its_arguments():
    with pytest.raises(ValueError, match="http"):
        ChatRewriter("localhost:8000", "m")
    with pytest.raises(ValueError, match="model"):
        ChatRewriter("http://localhost:8000", "")


# ------------------------------------------------------------------------------------------- integration

def add_caption_index(src: Path, dst: Path, dtype: str = "float16") -> Path:
    """A copy of a bundle with a caption index embedded by its own text encoder, as the exporter writes it."""
    shutil.copytree(src, dst)
    b = Bundle.load(dst)
    session = TextEncoderSession(b.read_verified("text_encoder.onnx"), b.read_verified("tokenizer.json"))
    words = ["a person walks forward.", "a person waves left hand.", "a person kicks twice.",
             "a person runs and then sits down.", "a person turns around.", "a person jumps."]
    index = CaptionIndex(words, session.encode(words), None, b.manifest.text_encoder.name)
    facts = index.save(dst / "captions.npz", dtype)
    m = json.loads((dst / "manifest.json").read_text())
    m["tca"] = {**facts, "method": "nearest", "top_k": 3}     # keys of older exports: read by nothing now
    m["files"]["captions.npz"] = {"bytes": (dst / "captions.npz").stat().st_size,
                                  "sha256": sha256_file(dst / "captions.npz")}
    (dst / "manifest.json").write_text(json.dumps(m, indent=2))
    return dst


@pytest.fixture(scope="module")
def indexed_bundle(toy_bundle, tmp_path_factory) -> Path:  # noqa: F811
    return add_caption_index(toy_bundle, tmp_path_factory.mktemp("tca") / "bundle")


def test_generate_align_returns_the_aligned_text(indexed_bundle):
    gen = MotionGenerator(indexed_bundle)
    m = gen.generate("the dude is walking forwards", seed=2, align=True)
    assert m.text == "the dude is walking forwards" and m.aligned_text == "a person walks forward."
    same = gen.generate("a person walks forward.", seed=2)
    assert np.array_equal(m.tokens, same.tokens) and same.aligned_text is None
    batch = gen.generate(["kick 2x", "the dude is walking forwards"], seed=[5, 2], align=True)
    assert [b.aligned_text for b in batch] == ["a person kicks twice.", "a person walks forward."]
    assert np.array_equal(batch[1].tokens, m.tokens)
    raw = gen.generate("the dude is walking forwards", seed=2)                 # off by default
    assert raw.aligned_text is None


def test_stream_align_matches_generate(indexed_bundle):
    gen = MotionGenerator(indexed_bundle)
    stream = gen.stream("he turns around", seed=1, seconds=1.6, align=True)
    assert stream.aligned_text == "a person turns around."
    frames = list(stream)
    m = gen.generate("he turns around", seed=1, seconds=1.6, align=True)
    assert np.allclose(np.stack([f.joints for f in frames]), m.joints, atol=1e-5)


def test_generate_with_a_custom_aligner_and_bad_align_values(indexed_bundle):
    class Shout(Aligner):
        def align(self, text):
            return AlignedPrompt("a person jumps.", method="custom")

    gen = MotionGenerator(indexed_bundle)
    assert gen.generate("whatever", seed=0, align=Shout()).aligned_text == "a person jumps."
    assert MotionGenerator(indexed_bundle, aligner=Shout()).generate("x", align=True).aligned_text == "a person jumps."
    with pytest.raises(ValueError, match="align"):
        gen.generate("a person jumps", align="yes")


def test_bundle_without_index_normalises_with_a_warning(toy_bundle):  # noqa: F811
    gen = MotionGenerator(toy_bundle)
    with pytest.warns(UserWarning, match="no caption index"):
        m = gen.generate("yo make the dude walk forward real quick lol", seed=0, align=True)
    assert m.aligned_text == "a person walks forward quickly."


def test_cli_align_flags(capsys, tmp_path, indexed_bundle, toy_bundle):  # noqa: F811
    out = tmp_path / "m.npy"
    code = main(["generate", "dude is walking forwards", "--bundle", str(indexed_bundle), "-o", str(out), "--align"])
    err = capsys.readouterr().err
    assert code == 0 and "aligned prompt: 'a person walks forward.'" in err
    code = main(["generate", "dude walks", "--bundle", str(toy_bundle), "-o", str(out), "--align"])
    err = capsys.readouterr().err
    assert code == 0 and "mogo: warning: this bundle has no caption index" in err and "Traceback" not in err
    code = main(["generate", "dude walks", "--bundle", str(toy_bundle), "-o", str(out), "--no-align"])
    assert code == 0 and "aligned" not in capsys.readouterr().err
    code = main(["generate", "x", "--bundle", str(toy_bundle), "-o", str(out), "--rewriter-model", "m"])
    assert code == 2 and "--rewriter-url" in capsys.readouterr().err
    # an unreachable rewriter: a warning line, then the offline path, exit 0
    code = main(["stream", "he turns around", "--bundle", str(indexed_bundle), "--seconds", "0.4",
                 "--rewriter-url", "http://127.0.0.1:9", "--rewriter-model", "m"])
    captured = capsys.readouterr()
    assert code == 0 and "mogo: warning: TCA rewriter" in captured.err
    assert "aligned prompt: 'a person turns around.'" in captured.err
    assert len(captured.out.splitlines()) == 8


def test_an_exported_bundle_ships_its_caption_index(tiny_bundle):
    """mogo-export writes captions.npz and the manifest's `tca` section; the runtime picks them up."""
    gen = MotionGenerator(tiny_bundle)
    tca = gen.bundle.manifest.tca
    assert gen.aligner.has_index and len(gen.aligner.index) == tca.count > 0
    assert gen.aligner.index.dim == gen.dims.text_dim and gen.aligner.lexical_weight == tca.lexical_weight
    caption = gen.aligner.index.captions[0]
    a = gen.aligner.align(caption)
    assert a.details["neighbours"][0][0][1] > 0.95                       # a training caption finds itself
    assert gen.generate(caption, seed=0, align=True).aligned_text == a.text
