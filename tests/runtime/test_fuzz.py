"""The fuzz suite's CI slice (tests/fuzz.py; `make fuzz` runs 10,000 cases with strace): a few hundred seeded
cases of corrupt bundles, hostile API calls and command lines, each in a worker process with a time bound."""
import collections
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import fuzz  # noqa: E402

from toy_bundle import toy_bundle  # noqa: E402,F401


def test_a_few_hundred_fuzz_cases_end_in_a_motion_or_a_clear_refusal(toy_bundle):  # noqa: F811
    cases = fuzz.make_cases(400, seed=20261124)
    results = fuzz.run(cases, toy_bundle)
    counts = collections.Counter((r["case"]["kind"], r["result"]) for r in results)
    print("fuzz: " + ", ".join(f"{k} {res} {n}" for (k, res), n in sorted(counts.items())))
    failed = [f"{r['result']}: {r['detail'][:200]} <- {str(r['case'])[:200]}" for r in results
              if r["result"] in fuzz.FAILURES]
    assert not failed, "\n".join(failed[:10])
    assert sum(n for (_, res), n in counts.items() if res == "ok") >= 50     # the suite exercises working paths
