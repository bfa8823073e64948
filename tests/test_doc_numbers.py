"""The benchmark numbers of the README and docs/ are their JSON's, and that JSON is not older than
the code it measures.

A number quoted from a benchmark JSON of docs/bench carries a marker that names its case, field and
format (``190.1<!--bench model.json:weathercity:time_ms /1000 .1f-->``; wcbench.bench.claims,
docs/guide.md "Numbers in the docs"). A JSON records the digests of the code it measured; one whose
code has changed since must be re-run, or listed with a date and a reason in docs/bench/stale.toml,
which this test reports.
"""

from __future__ import annotations

import warnings

from paths import REPO

from wcbench.bench.claims import BENCH_DIR, check_docs, check_freshness


def test_the_docs_quote_their_benchmark_json() -> None:
    report = check_docs(REPO, freshness=False)
    assert not report.problems, "numbers that are not their JSON's:\n" + "\n".join(report.problems)
    readme = check_docs(REPO, paths=[REPO / "README.md"], freshness=False)
    assert readme.claims > 0, "the README quotes benchmark numbers: their markers are gone"


def test_no_benchmark_json_is_older_than_its_code_unless_listed() -> None:
    problems, stale = check_freshness(REPO / BENCH_DIR, root=REPO)
    for line in stale:
        warnings.warn(f"stale benchmark JSON, listed in docs/bench/stale.toml: {line}", UserWarning, stacklevel=1)
    assert not problems, "\n".join(problems)
