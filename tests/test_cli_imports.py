"""netsim.cli builds only the parser a command needs (start-up latency), and that
parser parses exactly as the whole one does."""

from __future__ import annotations

import subprocess
import sys

import pytest

from netsim.cli import build_parser


def _subparsers(parser):
    return next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")


def test_top_level_listing_is_the_same():
    full, light = build_parser(), build_parser("")
    assert light.format_help() == full.format_help()
    names = {a.dest: a.help for a in _subparsers(full)._choices_actions}
    assert {a.dest: a.help for a in _subparsers(light)._choices_actions} == names


@pytest.mark.parametrize("argv", [
    ["run", "lcsys2022-heterogeneous", "--steps", "5", "--gains", "rate", "--rho", "0.5",
     "--ties", "highest", "--no-cache", "--no-progress"],
    ["analyze", "lcsys2022-homogeneous", "--tau-max", "4", "--workers", "2", "--json"],
    ["bench", "delay-tolerance", "lcsys2022-fig1", "--no-cache"],
    ["design", "lcsys2022-homogeneous", "--method", "lmi"],
    ["scenarios", "--json"],
])
def test_a_commands_parser_parses_as_the_whole_one(argv):
    assert vars(build_parser(argv[0]).parse_args(argv)) == vars(build_parser().parse_args(argv))
    sub = _subparsers(build_parser(argv[0])).choices[argv[0]]
    assert sub.format_help() == _subparsers(build_parser()).choices[argv[0]].format_help()


def test_help_and_run_do_not_import_what_they_do_not_use():
    code = ("import sys\nfrom netsim.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('netsim.bench', 'netsim.aoi', 'scipy.sparse', "
            "'networkx', 'cvxpy', 'matplotlib', 'mcap', 'simpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()[-1]
    assert out == "[]"
