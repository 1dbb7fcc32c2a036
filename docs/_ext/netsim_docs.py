"""Sphinx directives that generate reference pages from netsim's own code at build time.

- ``.. netsim-cli::`` renders every command of ``netsim`` from the argparse parser that
  ``netsim.cli.build_parser()`` builds (the same object ``netsim --help`` prints), as
  ``program``/``option`` descriptions, so every option is documented and can be linked
  with ``:option:``.
- ``.. netsim-scenario-schema::`` renders the scenario keys from the loader's own tables
  (``_SCHEMA``, ``DEFAULTS``, the link-model tables of :mod:`netsim.models.scenario`) and
  the loader's own message for a wrong value of each enumerated key (the validator is
  called with a bad value at build time). The one-line meanings are kept here, checked
  against the schema both ways: a key without a meaning, or a meaning for a key the
  loader does not know, is a build warning (and the strict build fails).

Nothing is copied by hand: a new option or key appears in the docs on the next build.
"""

from __future__ import annotations

import argparse
import copy
import warnings
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

logger = logging.getLogger(__name__)

_SPECIAL = set("\\`*_|[]<>:")


def escape(text: str) -> str:
    """``text`` as reST that renders literally (inline markup characters escaped)."""
    return "".join("\\" + c if c in _SPECIAL else c for c in " ".join(str(text).split()))


def _underline(title: str, char: str) -> list[str]:
    return [title, char * max(len(title), 4), ""]


# -- the command line ------------------------------------------------------------------


def _option_signature(action: argparse.Action) -> str:
    if not action.option_strings:
        name = action.metavar or action.dest
        return str(name)
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    metavar = action.metavar
    if metavar is None:
        metavar = ("{" + ",".join(map(str, action.choices)) + "}" if action.choices
                   else action.dest.upper())
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    return ", ".join(f"{opt} {metavar}" for opt in action.option_strings)


def _cli_lines(parser: argparse.ArgumentParser, prog: str, level: int) -> list[str]:
    chars = "~^\"'+"
    lines: list[str] = []
    formatter = parser._get_formatter()
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups,
                        prefix="")
    usage = formatter.format_help().strip()
    lines += ["::", ""] + ["   " + ln for ln in usage.splitlines()] + [""]
    if parser.description:
        lines += [escape(parser.description), ""]
    lines += [f".. program:: {prog}", ""]
    subactions = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            subactions.append(action)
            continue
        if action.help == argparse.SUPPRESS:
            continue
        lines += [f".. option:: {_option_signature(action)}", ""]
        text = action.help or ""
        if "%(" in text:
            text = text % {**vars(action), "prog": prog}
        if action.choices and not isinstance(action.choices, dict):
            text += f" (choices: {', '.join(map(str, action.choices))})"
        lines += ["   " + (escape(text) or "(no help text)"), ""]
    if parser.epilog:
        lines += ["::", ""] + ["   " + ln for ln in parser.epilog.splitlines()] + [""]
    for action in subactions:
        for name, sub in action.choices.items():
            lines += _underline(f"{prog} {name}", chars[level])
            lines += _cli_lines(sub, f"{prog} {name}", level + 1)
    return lines


class NetsimCli(SphinxDirective):
    """The whole ``netsim`` command line, from :func:`netsim.cli.build_parser`."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from netsim.cli import build_parser

        parser = build_parser()
        lines = _cli_lines(parser, "netsim", 0)
        return self._parse(lines)

    def _parse(self, lines: list[str]) -> list[nodes.Node]:
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(lines, source="netsim-cli"), node)
        return node.children


# -- the scenario schema ---------------------------------------------------------------

#: One line per key of the loader's schema. Checked against the code both ways.
MEANINGS: dict[str, str] = {
    "name": "the scenario's name (shown in results and traces)",
    "description": "free text",
    "run": "how the scenario runs (all keys optional)",
    "plant": "the linear plant and its sensors (required)",
    "network": "the agents, their links and consensus weights",
    "delays": "the delay model of every link",
    "gains": "the innovation gains of the consensus estimators",
    "links": "link models beyond a delay: distributions, loss, buffers, outages",
    "topology": "a time-varying graph sequence (AoI scenarios)",
    "options": "one table per estimator family, e.g. [options.aoi], [options.fusion]; "
               "each family checks its own keys",
    "time": "agent clocks (offset, drift_ppm, jitter), asynchronous sampling of a "
            "continuous plant (Ac, Qc, periods, phases), [time.trigger] "
            "(send-on-delta, periodic) and [time.sync] (two-way clock synchronisation); "
            "docs: Clocks, asynchronous sampling and triggers",
    "run.steps": "number of steps K",
    "run.trials": "Monte Carlo trials M",
    "run.seed": "root seed of the trial randomness: initial states, noise, "
                "time-varying delays",
    "run.sample_period": "Ts, the time of one step",
    "run.divergence_threshold": "an agent's error norm above it (or non-finite) is a "
                                "divergence; the trial stops there",
    "run.steady_state_fraction": "the last fraction of the trusted steps averaged into "
                                 "the steady-state MSE",
    "run.estimators": "the families to run: registered names, module:attribute, or "
                      "entry points",
    "plant.A": "n x n system matrix",
    "plant.C": "one m_i x n output matrix per sensor (= agent); [] measures nothing",
    "plant.Q": "process noise: a variance (times I) or an n x n matrix",
    "plant.R": "measurement noise: a variance, or a list with one entry (variance or "
               "matrix) per sensor",
    "plant.x0_mean": "mean of the initial state, also every estimator's prior "
                     "(default 0)",
    "plant.x0_cov": "covariance of the initial state (a variance or a matrix)",
    "plant.sensors": "N sensors cycling through the listed C (and R): sensor i is "
                     "C[i mod len(C)]",
    "network.topology": "cycle, random, geometric, or edges (with network.edges)",
    "network.agents": "number of agents N (must equal the number of sensors)",
    "network.edges": "the links [j, i] (i receives from j), each once, no self-loops",
    "network.weights": "random, uniform or lazy-metropolis consensus weights",
    "network.P": "the consensus weight matrix itself (replaces topology, weights, "
                 "edges, edge_probability and radius)",
    "network.seed": "seed of the random graph and random weights (fixed across trials)",
    "network.edge_probability": "random topology: each edge beyond a random "
                                "Hamiltonian cycle with this probability",
    "network.radius": "geometric topology: the connection radius (default: grown "
                      "until the graph is strongly connected)",
    "network.medium": "a simulated network that makes the delays and losses: model "
                      "(point-to-point, switched, tdma, csma, can, aloha, ns3) and its "
                      "parameters (docs: Delays made by the network)",
    "delays.model": "how link delays are made (see below)",
    "delays.tau": "the delay bound tau-bar, in steps",
    "delays.links": "model fixed or latency: a list of {from, to, delay}",
    "delays.default": "model fixed or latency: the delay of links not listed",
    "delays.seed": "seed of the heterogeneous realisation (fixed across trials)",
    "gains.method": "the gain design, as netsim design offers it",
    "gains.K": "method given: one n x n gain per agent",
    "gains.tau1": "design for delays up to tau1 (LCSYS2022 Discussion 5)",
    "gains.refine_from": "method refined: the design to start from",
    "links.delay": "a delay distribution table (distribution, its parameters, unit, mode)",
    "links.loss": "a loss model table (model and its parameters)",
    "links.buffer": "{capacity, policy}: messages in flight a link holds, and what it "
                    "drops when full",
    "links.outages": "sending steps [start, end) on which the link is down",
    "links.bandwidth": "bits per time unit: adds message_size / bandwidth to the delay",
    "links.message_size": "bits per message",
    "links.seed": "seed of the link randomness that is fixed across trials",
    "links.bound": "the tau-bar agents assume (default: from the distributions)",
    "links.per_link": "a list of tables overriding the defaults for single links",
    "topology.graphs": "the graph sequence: a list of edge lists [[j, i], ...]",
    "topology.period": "steps per graph of the sequence",
    "topology.down": "intervals in which a link is down",
    "topology.duty": "duty cycles of links",
}

#: Enumerated keys: the loader is called with a bad value and its message shown.
PROBES: list[tuple[tuple[str, ...], Any]] = [
    (("network", "topology"), "?"),
    (("network", "weights"), "?"),
    (("delays", "model"), "?"),
    (("gains", "method"), "?"),
    (("links", "delay"), {"distribution": "?"}),
    (("links", "delay"), {"distribution": "uniform", "low": 0, "high": 1, "mode": "?"}),
    (("links", "loss"), {"model": "?"}),
    (("links", "buffer"), {"capacity": 3, "policy": "?"}),
    (("network", "medium"), {"model": "?"}),
]


def _probe(path: tuple[str, ...], value: Any) -> str:
    from netsim.models.scenario import (
        ScenarioError,
        builtin_scenarios,
        parse_scenario,
        read_scenario_data,
    )

    data = copy.deepcopy(read_scenario_data(builtin_scenarios()["lcsys2022-heterogeneous"]))
    table = data
    for part in path[:-1]:
        table = table.setdefault(part, {})
    table[path[-1]] = value
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            parse_scenario(data)
    except ScenarioError as error:
        return str(error)
    logger.warning("netsim-scenario-schema: the loader accepted %s = %r", ".".join(path),
                   value)
    return ""


def _default(key: str, defaults: dict[str, Any]) -> str:
    found = [(k, v) for k, v in defaults.items() if k == key or k.startswith(key + " (")]
    return "; ".join(f"{v!r}" + (k[len(key):] if k != key else "") for k, v in found)


def _table(rows: list[tuple[str, ...]], header: tuple[str, ...], widths: str) -> list[str]:
    lines = [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for row in (header, *rows):
        first = True
        for cell in row:
            lines.append(("   * - " if first else "     - ") + (cell or ""))
            first = False
    return lines + [""]


class NetsimScenarioSchema(SphinxDirective):
    """Every scenario key, with its default and the loader's rules, from the code."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from netsim.models import scenario as sc

        schema: dict[str, set[str]] = sc._SCHEMA
        known = {k for k in schema[""]} | {f"{s}.{k}" for s in schema if s for k in schema[s]}
        for key in sorted(known - set(MEANINGS)):
            logger.warning("netsim-scenario-schema: scenario key %r has no meaning in "
                           "docs/_ext/netsim_docs.py", key)
        for key in sorted(set(MEANINGS) - known):
            logger.warning("netsim-scenario-schema: %r is documented but the loader does "
                           "not know it", key)
        lines: list[str] = []
        lines += _underline("Top-level keys and tables", "~")
        rows = [(f"``{k}``", escape(MEANINGS.get(k, ""))) for k in sorted(schema[""])]
        lines += _table(rows, ("key", "meaning"), "25 75")
        for section in [s for s in schema if s]:
            lines += _underline(f"[{section}]", "~")
            rows = []
            for key in sorted(schema[section]):
                full = f"{section}.{key}"
                default = _default(full, sc.DEFAULTS)
                rows.append((f"``{key}``", escape(default), escape(MEANINGS.get(full, ""))))
            lines += _table(rows, ("key", "default", "meaning"), "20 25 55")
        lines += _underline("[links] details", "~")
        lines += ["Keys of one ``links.per_link`` entry: "
                  + ", ".join(f"``{k}``" for k in sorted(sc._LINK_KEYS)) + ".", ""]
        rows = []
        for name, (required, optional) in sc._DISTRIBUTION_KEYS.items():
            units = sc._DISTRIBUTION_UNITS.get(name, ())
            rows.append((f"``{name}``", ", ".join(f"``{k}``" for k in sorted(required)),
                         ", ".join(f"``{k}``" for k in sorted(optional)),
                         ", ".join(units) or "n/a"))
        lines += ["Delay distributions (``links.delay.distribution``):", ""]
        lines += _table(rows, ("distribution", "required", "optional", "unit"), "20 30 25 25")
        rows = [(f"``{name}``", ", ".join(f"``{k}``" for k in sorted(keys)) or "none")
                for name, keys in sc._LOSS_KEYS.items()]
        lines += ["Loss models (``links.loss.model``):", ""]
        lines += _table(rows, ("model", "parameters"), "30 70")
        lines += _underline("What the loader says to a wrong value", "~")
        lines += ["Generated by calling the loader with a wrong value of each enumerated key "
                  "(every error names the key):", ""]
        for path, value in PROBES:
            message = _probe(path, value)
            lines += [f"- {escape(message)}"]
        lines += [""]
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(lines, source="netsim-schema"), node)
        return node.children


def setup(app: Any) -> dict[str, Any]:
    app.add_directive("netsim-cli", NetsimCli)
    app.add_directive("netsim-scenario-schema", NetsimScenarioSchema)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
