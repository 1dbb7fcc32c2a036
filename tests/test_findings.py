"""The documentation's "Findings so far" list (docs/findings.rst) is what `netsim claims`
reports (issue 18).

Every line of the generated block names one registry claim with its verdict, every
claim has one line, and the claims that need neither a search nor a bench run are run
here and must give the page's line exactly (the full comparison, searches included,
is ``python -m netsim.claims.findings --check``, run by the slow test).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from netsim.claims import CLAIM_IDS, REGISTRY, VERDICTS, run_claims
from netsim.claims.findings import finding_line, main, page_findings

PAGE = Path(__file__).resolve().parents[1] / "docs" / "findings.rst"
LINE = re.compile(r"^- ``(?P<id>[A-Za-z0-9-]+)`` \((?P<paper>[^,]+), .*?\): "
                  r"\*\*(?P<verdict>[a-z ]+)\*\*")
#: Claims whose checks need no search and no bench run (a few seconds together).
CHEAP = ("L-decay", "L-lemma2", "L-lemma1", "L-lemma3", "L-corollary1", "L-rho", "L-tau-star",
         "L-eq26", "L-hom-19", "T-lemma2", "T-decay", "T-rho", "T-bounds", "A-naive-growth",
         "D-table1", "D-cond77", "D-eq83", "D-ex1-numbers", "D-eq88", "D-eq93", "D-eq94",
         "D-eq95")


def _lines() -> list[str]:
    return page_findings(PAGE.read_text(encoding="utf-8"))


def test_every_finding_is_one_registry_claim_with_its_verdict():
    seen = []
    for line in _lines():
        m = LINE.match(line)
        assert m, f"not a generated finding line: {line[:80]}"
        claim = REGISTRY[m["id"]]
        assert m["paper"] == claim.paper and m["verdict"] in VERDICTS
        seen.append(m["id"])
    assert sorted(seen) == sorted(CLAIM_IDS)  # one line per claim, nothing else


#: A number printed at round-off level (|x| < 1e-12: "difference 4.7e-15"): its digits
#: vary between numpy/LAPACK builds, its magnitude does not.
_ROUNDOFF = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?e-(?:1[2-9]|[2-9]\d)\b")


def _roundoff_blind(line: str) -> str:
    return _ROUNDOFF.sub("<round-off>", line)


def test_cheap_findings_equal_a_fresh_run():
    assert not any(REGISTRY[c].searches for c in CHEAP)
    report = run_claims([REGISTRY[c] for c in CHEAP], seed=0, workers=1)
    page = {LINE.match(ln)["id"]: ln for ln in _lines()}
    for r in report.results:
        assert _roundoff_blind(page[r.claim.id]) == _roundoff_blind(finding_line(r)), (
            r.claim.id)


def test_roundoff_blind_keeps_every_other_number():
    line = "rho 0.8275, bound 1.2e-3, difference 4.7e-15, tiny -3e-16, step 12"
    assert _roundoff_blind(line) == ("rho 0.8275, bound 1.2e-3, difference <round-off>, "
                                     "tiny <round-off>, step 12")


@pytest.mark.slow
def test_page_findings_are_the_full_report():
    assert main([str(PAGE), "--check"]) == 0


def test_markdown_form_and_markers_round_trip():
    from netsim.claims.findings import (
        END,
        RST_END,
        RST_START,
        START,
        _rst_text,
        replace_findings,
    )

    assert _rst_text("tau* |x| a_b `c` \\") == "tau\\* \\|x\\| a\\_b \\`c\\` \\\\"
    for start, end in ((RST_START, RST_END), (START, END)):
        text = f"head\n\n{start}\n\n- old\n\n{end}\ntail\n"
        assert page_findings(text) == ["- old"]
        new = replace_findings(text, f"{start}\n\n- new\n\n{end}")
        assert page_findings(new) == ["- new"] and new.startswith("head") and new.endswith(
            "tail\n")
