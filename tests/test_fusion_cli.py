"""netsim fusion: Table I and Example 2 through the command line."""

from __future__ import annotations

import json

from netsim.cli import main


def test_table1_json_has_every_gamma_and_the_papers_verdicts(capsys):
    assert main(["fusion", "table1", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    text = json.dumps(data)
    for gamma in ("0.0", "0.5", "1.0"):
        assert gamma in text


def test_example2_json_and_bad_subcommand(capsys):
    assert main(["fusion", "example2", "--json"]) == 0
    json.loads(capsys.readouterr().out)
    assert main(["fusion"]) == 2
    assert "table1" in capsys.readouterr().err
    assert main(["fusion", "run", "dkfe-example2", "--trials", "0"]) == 2
