"""`mogo-eval actions`: compound prompts built from held-out captions, and the whole measurement on the tiny bundle."""
import json

import pytest

from mogo_eval.actions import NAMED_PROMPTS, compound_prompts
from mogo_eval.cli import main
from mogo_eval.quality import train_classifier
from mogo_export.data.procedural.families import FAMILIES, LAST_ONLY
from mogo_runtime.plan import plan_actions


@pytest.fixture(scope="module")
def data(tiny_checkpoints):
    return tiny_checkpoints.parent / "data"


def test_compound_prompts_name_distinct_families_in_order(data):
    families = sorted(FAMILIES)
    prompts = compound_prompts(data, families, 40, seed=3)
    assert [len(w) for _, w in prompts] == [2] * 20 + [3] * 20
    for text, want in prompts:
        assert len(set(want)) == len(want) and not set(want[:-1]) & LAST_ONLY, (text, want)
        assert len(plan_actions(text)) == len(want), text          # the runtime reads as many actions
    assert compound_prompts(data, families, 40, seed=3) == prompts != compound_prompts(data, families, 40, seed=4)


def test_the_whole_measurement_on_the_tiny_bundle(tiny_bundle, data, tmp_path, one_torch_thread):
    classifier = train_classifier(data, tmp_path, steps=30, progress=False)
    out = tmp_path / "actions.json"
    assert main(["actions", "--bundle", str(tiny_bundle), "--variant", "int8", "--prompts", "6", "--data", str(data),
                 "--classifier", str(classifier), "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["prompts"] == 6 and len(r["rows"]) == 6 and 0 <= r["all_in_order"] <= 1
    for row in r["rows"]:
        # the tiny model plays every action it is given: one span judged per action, in order
        assert row["split"] and len(row["got"]) == len(row["want"]), row
    assert r["all_in_order"] == sum(row["got"] == row["want"] for row in r["rows"]) / 6
    assert len(r["named"]["prompts"]) == len(NAMED_PROMPTS)
