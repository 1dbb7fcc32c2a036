"""The paper layout (issue 31): one module per paper, the commands only iterate registries.

Two structural checks, as tests/test_registry.py does for estimator families:

- the source of the claims, reproduce and bench packages names no paper (key, title,
  text file, module name, or the short names LCSYS / lcsys2022 / tolerant / aoi / dkfe),
  in code, strings or comments;
- a paper registered at test time, from this file, shows up in every registry the three
  commands read (claims, searches, reproduce items, bench presets, claim rows, delay
  bounds, delay-setting citations) without any of them being touched.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from netsim.papers import (
    BUILTIN_PAPERS,
    BenchRow,
    DelayBound,
    Paper,
    PaperError,
    Search,
    get_paper,
    papers,
    register_paper,
    unregister_paper,
)

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("netsim/claims", "netsim/reproduce", "netsim/bench")
#: Short names of the built-in papers, whatever their registry says.
SHORT_NAMES = ("lcsys", "lcsys2022", "delay-tolerant", "delay_tolerant", "tolerant", "aoi",
               "dkfe")


def paper_words() -> list[str]:
    """Every word that names a registered paper: keys, titles, text files, modules."""
    words = set(SHORT_NAMES)
    for p in papers():
        words |= {p.key, p.title, p.text_file, Path(p.text_file).stem}
    words |= {m.rsplit(".", 1)[-1] for m in BUILTIN_PAPERS}
    return sorted((w for w in words if w), key=len, reverse=True)


def mentions(path: Path, words: list[str]) -> list[str]:
    """``file:line: word`` for every line of ``path`` naming one of ``words``
    (case-insensitive)."""
    pattern = re.compile("|".join(re.escape(w) for w in words), re.IGNORECASE)
    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    found = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        hit = pattern.search(line)
        if hit:
            found.append(f"{where}:{number}: {hit.group(0)!r} in {line.strip()[:80]!r}")
    return found


def test_claims_reproduce_and_bench_name_no_paper():
    words = paper_words()
    offenders = []
    for package in PACKAGES:
        files = sorted((ROOT / package).rglob("*.py"))
        assert files, package
        for path in files:
            offenders += mentions(path, words)
    assert not offenders, "papers named outside netsim/papers:\n" + "\n".join(offenders)


def test_the_scan_finds_a_planted_name(tmp_path):
    # the check above can fail: names in code, strings and comments are found, in any case
    planted = tmp_path / "planted.py"
    planted.write_text("x = 1\n"
                       "from netsim.papers.dkfe import PAPER\n"
                       "# see the Delay-Tolerant paper\n"
                       "key = 'lcsys2022-fig1'\n"
                       "tolerance = 3  # not a paper name\n")
    found = mentions(planted, paper_words())
    assert [f.split(":")[1] for f in found] == ["2", "3", "4"]


def test_every_builtin_paper_declares_itself_in_its_own_module():
    keys = [p.key for p in papers()]
    assert keys[:4] == ["LCSYS2022", "delay-tolerant", "aoi", "dkfe"]
    for p in papers()[:4]:
        module = BUILTIN_PAPERS[keys.index(p.key)]
        assert (ROOT / (module.replace(".", "/") + ".py")).exists()
        assert p.claims and p.items, p.key
        assert all(c.paper == p.key for c in p.claims)
        assert all(i.paper == p.key for i in p.items)
        for scenario in p.scenarios:
            assert (ROOT / "models" / "scenarios" / f"{scenario}.toml").exists(), scenario
    assert get_paper("lcsys2022") is get_paper("LCSYS2022")
    with pytest.raises(PaperError, match="unknown paper"):
        get_paper("nope")
    with pytest.raises(PaperError, match="already registered"):
        register_paper(Paper(key="aoi", title="x", text_file="x.txt"))


# -- a toy paper, registered here -----------------------------------------------------------


def _check(context):
    from netsim.claims import PROVED, Outcome

    found = context.cached("search:Z-search", lambda: None)
    return Outcome(PROVED, f"toy: search found {found}", {"found": found})


def _search(seed, instances, deadline):
    return {"instances": instances, "spawned": not isinstance(seed, int)}


def _row(data):
    from netsim.bench.claims import claim_row

    return claim_row("Z-claim", "toy-paper", "toy statement", f"{len(data['cells'])} cells",
                     True)


def _build(ctx):
    from netsim.reproduce.items import ItemResult, figure, write_csv

    fig = figure(figsize=(2, 2))
    fig.subplots().plot([0, 1], [1, 0])
    name = write_csv(ctx.out / "toy-fig1.csv", ("k", "v"), [(0, 1.0), (1, 0.0)])
    return ItemResult(fig, [name], ["ours: a line"])


@pytest.fixture
def toy():
    from netsim.bench.presets import Preset, SweepPreset
    from netsim.claims import Claim
    from netsim.reproduce.items import Item

    paper = Paper(
        key="toy-paper", title="A toy paper", text_file="toy-paper.txt",
        scenarios=("lcsys2022-heterogeneous",),
        claims=(Claim("Z-claim", "toy-paper", "Fig. 1", "a toy statement", (), "theorem",
                      _check, searches=("Z-search",)),),
        items=(Item("toy-fig1", "toy-paper", "Fig. 1", "caption", "says", (), ("Z-claim",),
                    _build),),
        presets=(Preset("toy-preset", "lcsys2022-heterogeneous", (1,), ("homogeneous",),
                        2, 10, "compensated", "a toy preset", ("Z-claim",)),),
        bench_rows=(BenchRow("Z-claim", _row, default_rank=5),),
        searches=(Search("Z-search", _search),),
        delay_bounds=(DelayBound(key="bound_toy", run_key="bound_toy_run", name="toy bound",
                                 compute=lambda P, A, C, L, tau: 0.5 ** (tau + 1),
                                 recursions=(), prediction="any", predicted_by="toy",
                                 help="the toy bound", legend="toy (none)",
                                 prediction_legend="toy: none"),),
        delay_settings={"homogeneous": "Fig. 9"},
        sweeps=(SweepPreset("toy-sweep", "lcsys2022-heterogeneous", {"loss": (0.0, 0.1)},
                            ("compensated",), 2, 10, "a toy sweep"),),
    )
    register_paper(paper)
    yield paper
    unregister_paper(paper.key)


def test_a_registered_paper_reaches_the_claims(toy):
    from netsim.claims import get_claim, run_claims, select
    from netsim.claims.registry import REGISTRY
    from netsim.claims.searches import run_search, searches

    assert [c.id for c in select(["TOY-PAPER"])] == ["Z-claim"]
    assert get_claim("Z-claim") is toy.claims[0] and "Z-claim" in REGISTRY
    assert list(searches())[-1] == "Z-search"
    assert run_search("Z-search", 3, instances=7) == {"instances": 7, "spawned": True}
    report = run_claims(select(["toy-paper"]), workers=1)
    (result,) = report.results
    assert result.outcome.numbers["found"] == {"instances": 400, "spawned": True}


def test_a_registered_paper_reaches_reproduce(toy, tmp_path):
    import argparse

    from netsim.reproduce import add_reproduce_parser, items_for, reproduce

    assert [i.id for i in items_for(["toy-paper"])] == ["toy-fig1"]
    parser = argparse.ArgumentParser()
    add_reproduce_parser(parser.add_subparsers())
    result = reproduce(["toy-paper"], out=tmp_path, trials=1, workers=1)
    assert (tmp_path / "toy-fig1.png").read_bytes()[:4] == b"\x89PNG"
    text = result.report.read_text()
    assert "## A toy paper" in text and "| Z-claim |" in text


def test_a_registered_paper_reaches_the_bench(toy, tmp_path):
    from netsim.models.scenario import resolve_scenario

    from netsim.bench.claims import bench_rows, default_rows
    from netsim.bench.delay_tolerance import run_delay_tolerance
    from netsim.bench.presets import delay_settings, presets, sweep_presets
    from netsim.claims.search import ScalarInstance, write_scenario

    assert presets()["toy-preset"] is toy.presets[0]
    assert sweep_presets()["toy-sweep"] is toy.sweeps[0]
    assert bench_rows()["Z-claim"] is _row and default_rows()[-1] == "Z-claim"
    assert delay_settings()["homogeneous"][1].endswith("toy-paper Fig. 9)")
    p = toy.presets[0]
    # a scalar scenario with given gains (no gain design): the preset's run, small
    small = ScalarInstance(0.9, ((0.5, 0.5), (0.5, 0.5)), (1.0, 1.0), (0.5, 0.5))
    path = write_scenario(small, 1, tmp_path, "toy", "toy scenario")
    data = run_delay_tolerance(resolve_scenario(str(path)), taus=p.taus, delays=p.delays,
                               trials=p.trials, steps=p.steps, seed=0, families=[p.focus],
                               preset=p, executor="serial", progress=False)
    for cell in data["cells"]:
        # the toy bound sits beside the papers' own, computed at the cell's tau
        assert cell["analytics"]["bound_toy"] == pytest.approx(0.5 ** (cell["tau"] + 1))
    assert data["claims"] == [_row(data)]
    assert np.isfinite(data["cells"][0]["analytics"]["bound"])
