"""A plugin that is not an estimator family, or fails, is one line; entry points by name.

Issue 29: a name that resolves to something other than an estimator family (a builtin
such as ``os:system``, a standard-library function, a constant, a module, a class whose
constructor does not take ``cls(setup)``), a plugin module that raises or calls
``sys.exit()`` on import, and a factory or constructor that fails on the host's
arguments are each refused with one line naming the scenario key or option and the
object (exit 2 from ``netsim run``; :class:`FamilyError`, never ``SystemExit``, from
Python). An entry point runs, and its results are reported, under the entry point's
name, whatever its class calls itself, and resolving it again in the same process (a
second ``netsim.run``) returns the same family.

Entry points are simulated as in tests/test_plugins.py: a ``*.dist-info`` folder with an
``entry_points.txt``, here put on ``sys.path`` of this process (monkeypatch), which
:mod:`importlib.metadata` reads; each test writes modules and entry points of its own
names (imported modules and resolved families are cached per process).
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from netsim.estimators.registry import (
    FamilyError,
    family_names,
    get_family,
    unregister,
)
from netsim.models.scenario import ScenarioError

import netsim
import netsim.api
from netsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = "lcsys2022-heterogeneous"
SCENARIO_FILE = ROOT / "models" / "scenarios" / f"{SCENARIO}.toml"
BUILTIN_LIST = 'estimators = ["compensated", "uncompensated", "block", "centralized-kf"]'
SMALL = ("--steps", "20", "--trials", "1", "--no-progress")
PREFIX = "netsim run: error: "


def run_cli(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line_error(code: int, out: str, err: str, *fragments: str) -> None:
    """Exit 2, nothing on stdout, exactly one stderr line, the fragments in it."""
    assert "Traceback" not in err, err
    assert code == 2, err
    assert out == "", out
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert err.startswith(PREFIX), err
    for fragment in fragments:
        assert fragment in err, (fragment, err)


def _module(tmp_path: Path, source: str) -> str:
    """Write a plugin module of a name of this test's own; return the name."""
    name = f"plugin_{tmp_path.name.replace('-', '_').lower()}"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
    return name


def _scenario(tmp_path: Path, estimator: str) -> Path:
    """The built-in scenario as a file beside the plugin, listing ``estimator`` second."""
    text = SCENARIO_FILE.read_text()
    assert BUILTIN_LIST in text
    path = tmp_path / "plugin.toml"
    path.write_text(text.replace(BUILTIN_LIST, f'estimators = ["compensated", "{estimator}"]'))
    return path


@pytest.fixture(autouse=True)
def forget():
    """Unregister the families a test resolved (the registry lives for the process), so
    that no later test sees them."""
    before = set(family_names(include_entry_points=False))
    yield
    for name in set(family_names(include_entry_points=False)) - before:
        unregister(name)


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    """``tmp_path`` on the import path (where --estimators module:attribute looks)."""
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


GOOD_CLASS = """
    import numpy as np

    class Hold:
        name = "{short}"

        def __init__(self, setup):
            self.estimate = np.array(setup.prior_mean, dtype=float)

        def message_arrived(self, sender, sent_step, payload):
            return False

        def step(self, k, y):
            return self.estimate
"""


# -- names that resolve to something other than an estimator family -------------

NOT_FAMILIES = [
    ("os:system", "is a builtin function (posix.system), not an estimator family"),
    ("builtins:print", "is a builtin function (builtins.print), not an estimator family"),
    ("json:loads", "is a function of the standard library (json.loads), not an estimator "
     "family"),
    ("math:pi", "is a float object, not an estimator family"),
    ("os:path", "is a module"),
    ("netsim.estimators.contract:Estimator", "class Estimator is abstract"),
]


@pytest.mark.parametrize(("reference", "what"), NOT_FAMILIES)
def test_cli_refuses_what_is_not_an_estimator_family(capsys, reference, what):
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", reference, *SMALL)
    one_line_error(code, out, err, "--estimators[0]", repr(reference), what)


@pytest.mark.parametrize(("reference", "what"), NOT_FAMILIES[:3])
def test_the_refusal_names_what_a_family_is(capsys, reference, what):
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", reference, *SMALL)
    one_line_error(code, out, err, "message_arrived() and step()", "cls(setup)",
                   "(FamilyContext) -> list of AgentPlan", "EstimatorFamily")


@pytest.mark.parametrize(("reference", "what"), NOT_FAMILIES)
def test_python_api_refuses_what_is_not_an_estimator_family(reference, what):
    with pytest.raises(FamilyError, match="estimators") as caught:
        netsim.run(SCENARIO, steps=5, trials=1, estimators=[reference])
    assert repr(reference) in str(caught.value) and what in str(caught.value)
    with pytest.raises(FamilyError, match=what.split(" (")[0]):
        get_family(reference, "run.estimators[0]")


def test_a_builtin_is_refused_before_it_is_called(capsys):
    # builtins:print would print the host's FamilyContext; nothing reaches stdout
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", "compensated,"
                             "builtins:print", *SMALL)
    one_line_error(code, out, err, "--estimators[1]", "'builtins:print'")


def test_an_estimator_instance_is_told_to_name_its_class(capsys, on_path):
    module = _module(on_path, GOOD_CLASS.format(short="held") + """
    class _Setup:
        prior_mean = [0.0]

    one = Hold(_Setup())
    """)
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", f"{module}:one", *SMALL)
    one_line_error(code, out, err, "--estimators[0]", f"'{module}:one'", "an instance of Hold",
                   "name the class")


# -- constructors and factories that do not take the host's argument ------------

CONSTRUCTORS = """
    import numpy as np

    class _Contract:
        def message_arrived(self, sender, sent_step, payload):
            return False

        def step(self, k, y):
            return np.zeros(6)

    class NoArgument(_Contract):
        def __init__(self):
            self.estimate = np.zeros(6)

    class ThreeArguments(_Contract):
        def __init__(self, A, C, Q):
            self.estimate = np.zeros(6)

    class Subscripts(_Contract):
        def __init__(self, setup):
            self.estimate = np.zeros(6) + setup["A"]

    class Exits(_Contract):
        def __init__(self, setup):
            raise SystemExit(3)

    def two_arguments(context, extra):
        return []

    def raises(context):
        raise KeyError("no such thing")

    def returns_none(context):
        return None
"""


@pytest.mark.parametrize(("attribute", "fragments"), [
    ("NoArgument", ("class NoArgument cannot be built as NoArgument(setup)",
                    "constructor takes ()")),
    ("ThreeArguments", ("class ThreeArguments cannot be built as ThreeArguments(setup)",
                        "missing a required argument: 'C'")),
    ("two_arguments", ("cannot be called as a factory, factory(context)",
                       "missing a required argument: 'extra'")),
])
def test_signature_that_does_not_take_the_hosts_argument(capsys, on_path, attribute,
                                                          fragments):
    module = _module(on_path, CONSTRUCTORS)
    reference = f"{module}:{attribute}"
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", reference, *SMALL)
    one_line_error(code, out, err, "--estimators[0]", repr(reference), *fragments)
    # named in a scenario file: the scenario key and its index
    code, out, err = run_cli(capsys, "run", str(_scenario(on_path, reference)), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", repr(reference), *fragments)
    with pytest.raises(FamilyError, match="estimators"):
        netsim.run(SCENARIO, steps=5, trials=1, estimators=[reference])


@pytest.mark.parametrize(("attribute", "fragments"), [
    ("Subscripts", ("agent 0: Subscripts(setup) failed: TypeError:", "not subscriptable")),
    ("Exits", ("agent 0: Exits(setup) failed: it called sys.exit(3)",)),
    ("raises", ("its factory raises(context) failed: KeyError: 'no such thing'",)),
    ("returns_none", ("its factory returns_none(context) returned None, not a list of "
                      "AgentPlan",)),
])
def test_factory_or_constructor_failing_on_the_hosts_argument(capsys, on_path, attribute,
                                                              fragments):
    module = _module(on_path, CONSTRUCTORS)
    reference = f"{module}:{attribute}"
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", reference, *SMALL)
    one_line_error(code, out, err, "--estimators", reference, *fragments)
    code, out, err = run_cli(capsys, "run", str(_scenario(on_path, reference)), *SMALL)
    one_line_error(code, out, err, "run.estimators", reference, *fragments)
    # from Python: a FamilyError (not SystemExit), caused by the plugin's own error
    with pytest.raises(FamilyError, match="failed|returned None") as caught:
        netsim.run(SCENARIO, steps=5, trials=1, estimators=[reference], engine="events")
    assert all(f in str(caught.value) for f in fragments)
    if attribute != "returns_none":
        assert caught.value.__cause__ is not None


# -- plugin modules that raise or exit on import ---------------------------------

IMPORT_FAILURES = [
    ("raise RuntimeError('boom\\nand a second line')\n",
     "failed: RuntimeError: boom and a second line"),
    ("import sys\nsys.exit(0)\n", "failed: it called sys.exit(0)"),
    ("import sys\nsys.exit('bye')\n", "failed: it called sys.exit('bye')"),
    ("raise SystemExit\n", "failed: it called sys.exit(None)"),
]


@pytest.mark.parametrize(("source", "what"), IMPORT_FAILURES)
def test_plugin_module_failing_on_import(capsys, on_path, source, what):
    module = _module(on_path, source)
    reference = f"{module}:Filter"
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", reference, *SMALL)
    one_line_error(code, out, err, "--estimators[0]", f"importing '{module}'", repr(reference),
                   what)
    code, out, err = run_cli(capsys, "run", str(_scenario(on_path, reference)), *SMALL)
    one_line_error(code, out, err, "run.estimators[1]", repr(reference), what)


@pytest.mark.parametrize(("source", "what"), IMPORT_FAILURES)
def test_python_api_raises_family_error_not_system_exit(on_path, source, what):
    module = _module(on_path, source)
    reference = f"{module}:Filter"
    with pytest.raises(FamilyError, match="estimators") as caught:
        netsim.run(SCENARIO, steps=5, trials=1, estimators=[reference])
    assert what in str(caught.value) and "\n" not in str(caught.value)
    with pytest.raises(ScenarioError, match=r"run\.estimators\[1\]"):
        netsim.load_scenario(_scenario(on_path, reference))


def test_family_error_survives_pickling():
    # raised in a sweep's worker process, it must reach the parent intact
    error = FamilyError("run.estimators[1]", "'m:X' is a float object, not an estimator family")
    again = pickle.loads(pickle.dumps(error))
    assert isinstance(again, FamilyError)
    assert (again.key, str(again)) == (error.key, str(error))


# -- entry points ----------------------------------------------------------------


def _entry_point(tmp_path: Path, monkeypatch, entries: dict[str, str],
                 source: str | None = None) -> str:
    """Install (on sys.path) a distribution declaring ``entries`` (name -> attribute of
    the module written from ``source``, or a full ``module:attribute``); return the
    module's name."""
    module = f"epkg_{tmp_path.name.replace('-', '_').lower()}"
    site = tmp_path / "site"
    dist = site / f"{module}-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
    lines = [f"{name} = {value if ':' in value else f'{module}:{value}'}"
             for name, value in entries.items()]
    (dist / "entry_points.txt").write_text("[netsim.estimators]\n" + "\n".join(lines) + "\n")
    if source is not None:
        (site / f"{module}.py").write_text(textwrap.dedent(source))
    monkeypatch.syspath_prepend(str(site))
    return module


def test_entry_point_runs_under_its_own_name_not_its_class_name(capsys, tmp_path,
                                                                 monkeypatch):
    ep = f"my-kf-{tmp_path.name.lower()}"
    _entry_point(tmp_path, monkeypatch, {ep: "Hold"}, GOOD_CLASS.format(short="kf-cls"))
    assert ep in family_names()
    for _ in range(2):  # the same command twice in one process
        code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", f"{ep},compensated",
                                 *SMALL, "--json")
        assert code == 0, err
        assert list(json.loads(out)["estimators"]) == [ep, "compensated"]
    family = get_family(ep)
    assert (family.name, family.reference, family.source) == (ep, ep, "entry-point")
    assert "kf-cls" not in family_names()  # the class's name is not a second name


def test_entry_point_in_repeated_python_runs(tmp_path, monkeypatch):
    # a notebook cell re-run: netsim.run and netsim.api.run, again and again
    ep = f"ep-hold-{tmp_path.name.lower()}"
    _entry_point(tmp_path, monkeypatch, {ep: "Hold"}, GOOD_CLASS.format(short="hold"))
    first = netsim.run(SCENARIO, steps=10, trials=2, estimators=[ep])
    for run in (netsim.run, netsim.api.run, netsim.run):
        again = run(SCENARIO, steps=10, trials=2, estimators=[ep])
        assert list(again.families) == [ep]
        assert (again[ep].squared_errors == first[ep].squared_errors).all()
    one = netsim.run_one(SCENARIO, ep, trial=1, steps=10)
    assert (one.squared_errors == first[ep].squared_errors[1]).all()


def test_entry_point_family_object_of_another_name(tmp_path, monkeypatch):
    ep = f"ep-fam-{tmp_path.name.lower()}"
    _entry_point(tmp_path, monkeypatch, {ep: "FAMILY"}, GOOD_CLASS.format(short="x") + """
    from netsim.estimators.registry import AgentPlan, EstimatorFamily

    def build(context):
        return [AgentPlan(Hold(context.agent_setup(i)), (i,), ())
                for i in range(context.scenario.n_agents)]

    FAMILY = EstimatorFamily(name="internal-name", build=build)
    """)
    for _ in range(2):
        result = netsim.run(SCENARIO, steps=10, trials=1, estimators=[ep])
        assert list(result.families) == [ep]
    assert "internal-name" not in family_names()


@pytest.mark.parametrize(("value", "source", "what"), [
    ("os:system", None, "is a builtin function (posix.system), not an estimator family"),
    ("Filter", "raise RuntimeError('boom')\n", "failed to load: RuntimeError: boom"),
    ("Filter", "import sys\nsys.exit(0)\n", "failed to load: it called sys.exit(0)"),
    ("Missing", "X = 1\n", "failed to load: AttributeError"),
])
def test_entry_point_that_is_not_a_family_or_fails(capsys, tmp_path, monkeypatch,
                                                   value, source, what):
    ep = f"ep-bad-{tmp_path.name.lower()}"
    _entry_point(tmp_path, monkeypatch, {ep: value}, source)
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators", ep, *SMALL)
    one_line_error(code, out, err, "--estimators[0]", repr(ep), what)
    with pytest.raises(FamilyError, match="estimators"):
        netsim.run(SCENARIO, steps=5, trials=1, estimators=[ep])


def test_one_class_under_two_names_is_listed_twice(capsys, on_path):
    module = _module(on_path, GOOD_CLASS.format(short="short-hold"))
    reference = f"{module}:Hold"
    code, out, err = run_cli(capsys, "run", SCENARIO, "--estimators",
                             f"{reference},short-hold", *SMALL)
    one_line_error(code, out, err, "--estimators[1]", "'short-hold' is listed twice",
                   f"as '{reference}'")


# -- module:attribute from the current directory (issue 30) ---------------------------


def test_plugin_in_the_current_directory_beside_a_builtin_scenario(tmp_path):
    """``--estimators mod:Cls`` with a built-in scenario finds mod.py in the current
    directory without PYTHONPATH (a fresh ``netsim`` process: the console script's
    sys.path has no current directory)."""
    (tmp_path / "cwd_plugin_issue30.py").write_text(
        (ROOT / "examples" / "consensus_on_information.py").read_text(encoding="utf-8"),
        encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    script = "import sys; from netsim.cli import main; sys.exit(main(sys.argv[1:]))"
    run = subprocess.run(  # -P: no current directory on sys.path, as the console script
        [sys.executable, "-P", "-c", script, "run", "lcsys2022-homogeneous", "--estimators",
         "compensated,cwd_plugin_issue30:ConsensusOnInformation", "--engine", "events",
         "--steps", "20", "--trials", "1", "--no-progress", "--json"],
        capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert run.returncode == 0, run.stderr
    names = list(json.loads(run.stdout)["estimators"])
    assert names == ["compensated", "consensus-on-information"] or (
        len(names) == 2 and names[0] == "compensated"), names


def test_module_not_found_says_where_it_looked(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["run", "lcsys2022-homogeneous", "--estimators", "nosuchmod_issue30:X",
                 "--steps", "5", "--trials", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"looked in the current directory {tmp_path}" in err
    assert "and the Python path" in err


def test_a_plugin_whose_step_raises_is_named_in_one_line(tmp_path, monkeypatch, capsys):
    """The estimator's own exception, not a numpy error from the kernel's bookkeeping."""
    (tmp_path / "badstep_issue29.py").write_text(
        "import numpy as np\n"
        "class Bad:\n"
        "    def __init__(self, setup):\n"
        "        self.x = np.zeros(setup.A.shape[0])\n"
        "    def message_arrived(self, sender, sent_step, payload):\n"
        "        return True\n"
        "    def step(self, k, y):\n"
        "        if k == 2:\n"
        "            raise ZeroDivisionError('plugin bug')\n"
        "        return self.x\n"
        "    def estimate(self):\n"
        "        return self.x\n")
    monkeypatch.chdir(tmp_path)
    code = main(["run", "lcsys2022-heterogeneous", "--estimators", "badstep_issue29:Bad",
                 "--steps", "5", "--trials", "1", "--no-progress"])
    err = [line for line in capsys.readouterr().err.splitlines() if "note:" not in line]
    assert code == 2 and len(err) == 1, err
    assert err[0] == ("netsim run: error: estimator badstep_issue29.Bad of agent 0 failed "
                      "in step() at step 2: ZeroDivisionError: plugin bug")
