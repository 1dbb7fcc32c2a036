"""The estimator registry: one place that knows the families.

The structural check: no code outside a family's own module and the registry compares
a value with a family's name (``family == "block"``, ``name in ("aoi", ...)``); every
other part asks the registry what a family needs and supports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from netsim.estimators.registry import (
    RECURSION_BLOCK,
    RECURSION_COMPENSATED,
    RECURSION_UNCOMPENSATED,
    EstimatorFamily,
    FamilyContext,
    families,
    family_names,
    get_family,
)

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("netsim", "models", "estimators", "traces")


def _declaring_module(family: EstimatorFamily) -> Path:
    module = family.build.__module__  # the module whose factory builds the agents
    parts = module.split(".")
    folder = {"models": "models", "estimators": "estimators", "traces": "traces"}
    if len(parts) > 2 and parts[1] in folder:
        return ROOT / folder[parts[1]] / (parts[2] + ".py")
    return ROOT / "/".join(parts[:-1]) / (parts[-1] + ".py")


def _names_in(node: ast.AST) -> list[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [n for element in node.elts for n in _names_in(element)]
    return []


def comparisons_with_family_names(path: Path, names: set[str]) -> list[str]:
    """Every comparison in ``path`` of a value with a family-name constant."""
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for operand in [node.left, *node.comparators]:
                hits = [n for n in _names_in(operand) if n in names]
                if hits:
                    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
                    found.append(f"{where}:{node.lineno}: {hits}")
    return found


def test_no_family_name_is_compared_outside_its_module_and_the_registry():
    declared = {f.name: _declaring_module(f) for f in families()}
    names = set(declared)
    allowed = {ROOT / "estimators" / "registry.py", *declared.values()}
    offenders = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if path in allowed:
                continue
            offenders += comparisons_with_family_names(path, names)
    assert not offenders, "family names compared outside the registry:\n" + "\n".join(
        offenders)


def test_the_check_finds_a_comparison(tmp_path):
    # the check above can fail: planted comparisons are found, other strings are not
    planted = tmp_path / "planted.py"
    planted.write_text("def f(family, d):\n"
                       "    x = d.get('block')\n"
                       "    return family in ('block', 'x') or 'aoi' == family\n")
    found = comparisons_with_family_names(planted, {"block", "aoi"})
    assert [line.split(": ", 1)[1] for line in found] == ["['block']", "['aoi']"]


def test_every_builtin_family_declares_itself_in_its_own_module():
    builtin = [f for f in families() if f.source == "builtin"]
    assert {f.name for f in builtin} == {
        "compensated", "uncompensated", "block", "centralized-kf", "local-kf",
        "aoi", "naive-uniform", "naive-tree", "dkfe", "sdkfe", "odkfe",
        "kcf", "ci", "diffkf"}
    for family in builtin:
        assert _declaring_module(family).exists(), family.name
        assert family.description and family.paper, family.name
    assert family_names()[:4] == ["compensated", "uncompensated", "block", "centralized-kf"]


def test_declared_traits_match_what_the_families_do():
    # the traits are claims about the estimator objects: check them on built agents
    from netsim.models.scenario import resolve_scenario

    from netsim.runner import scenario_gains

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    gains = scenario_gains(scenario)
    for name, recursion in (("compensated", RECURSION_COMPENSATED),
                            ("uncompensated", RECURSION_UNCOMPENSATED),
                            ("block", RECURSION_BLOCK), ("centralized-kf", None),
                            ("local-kf", None)):
        family = get_family(name)
        assert family.error_recursion == recursion
        plans = family.agents(FamilyContext(scenario, gains if family.needs_gains else None,
                                            0, name))
        assert len(plans) == (1 if family.centralised else scenario.n_agents)
        # a family that reports effective delays is one with a recursion to replay
        assert hasattr(plans[0].estimator, "last_delays") == (recursion is not None)
        if family.centralised:
            assert plans[0].sensors == tuple(range(scenario.plant.n_sensors))


def test_a_family_that_needs_gains_refuses_to_build_without():
    from netsim.models.scenario import resolve_scenario

    with pytest.raises(ValueError, match="needs gains"):
        get_family("compensated").agents(
            FamilyContext(resolve_scenario("lcsys2022-heterogeneous"), None, 0))


def test_the_builtin_family_table_names_each_familys_module():
    """BUILTIN_FAMILIES (a run imports only its families' modules) is what the built-in
    modules register."""
    from netsim.estimators.registry import BUILTIN_FAMILIES

    declared = {f.name: f.build.__module__ for f in families() if f.source == "builtin"}
    assert declared == BUILTIN_FAMILIES
