"""The TCA measurement (mogo_eval.tca_eval): what each compared method conditions on, the table, the arguments.

Generation and the classifier are what mogo_eval.quality's tests cover; here a bag-of-words index stands in.
"""
import hashlib

import numpy as np
import pytest

from mogo_eval.tca_eval import METHODS, aligned_texts, main, table
from mogo_runtime.tca import CaptionIndex

CAPTIONS = ["a person walks backward.", "a person walks forward slowly.", "a person jumps in place twice.",
            "a person waves with the left hand.", "a person waves with the right hand."]


def bag_of_words(texts):
    out = []
    for t in texts:
        words = [w.strip(".,") for w in t.lower().split() if w.strip(".,") not in {"a", "person", "the", "with"}]
        v = sum((np.random.default_rng(int(hashlib.sha1(w.encode()).hexdigest()[:8], 16)).standard_normal(32)
                 for w in words), np.zeros(32)) + 1e-3
        out.append(v / np.linalg.norm(v))
    return np.array(out, np.float32)


@pytest.fixture(scope="module")
def index():
    return CaptionIndex(CAPTIONS, bag_of_words(CAPTIONS), None, "bag-of-words")


def test_each_method_conditions_on_its_text(index):
    prompts = ["dude backpedals", "lol ok", "guy waves with his right hand"]
    got = {m: aligned_texts(m, prompts, index, bag_of_words) for m in METHODS}
    assert got["raw"] == prompts
    assert got["normalize"] == ["a person walks backward.", "lol ok", "a person waves with his right hand."]
    assert got["nearest"] == ["a person walks backward.", "lol ok", "a person waves with the right hand."]
    assert got["nearest-nolex"][1] == "lol ok"                          # nothing recognised: as typed


def test_table_and_arguments(capsys):
    cell = {"accuracy": 0.5, "ci95": [0.25, 0.75], "prompts": 4}
    results = {"methods": {"raw": {"summary": {"dev": cell}},
                           "nearest": {"summary": {"dev": {**cell, "vs_raw": {"delta": 0.25, "ci95": [0.0, 0.5]}}}}}}
    assert table(results).splitlines()[-1] == "| nearest | 0.500 [0.25, 0.75]<br>+0.250 [+0.00, +0.50] |"
    with pytest.raises(SystemExit):
        main(["--bundle", "b", "--data", "d", "--checkpoints", "c", "--methods", "raw,blend"])
    assert "unknown method/set ['blend']" in capsys.readouterr().err
