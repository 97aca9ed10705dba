"""Which chain a one-process run simulates (diagrams/scenario.py: ``chain``; the ``simulate``
command's ``--chain``).

Oracles: the bad-input contract of the suite (exit 2, one line naming the key path and the
value, nothing written; tests/bad_input_helpers.py), and for a run, what is known of each
chain without the code under test: the paper's chain has no onboard guard (no guard record,
no guard metrics), the deployed chain has one.
"""

import json

import pytest
from bad_input_helpers import assert_one_line_error, run, snapshot

import telesmooth.scripts.simulate_report as simulate_report
from telesmooth.diagrams.scenario import CHAINS, LoadScenario, Scenario

SHORT = ("{haptic: {source: synthetic, synthetic: {duration_s: 5.0, hold_start_s: 0.5, "
         "hold_end_s: 0.5}}, settle_s: 1.0%s}")
FAULTS = "link: {faults: {loss_probability: 0.1}}"


def test_the_chains_and_the_default():
    # Catches: a default other than the deployed chain (simulate would no longer run what
    # is deployed), or another spelling of the chains.
    assert CHAINS == ("deployed", "paper")
    assert Scenario().chain == "deployed"
    assert LoadScenario().chain == "deployed"


@pytest.mark.parametrize("text, words", [
    ("{chain: papr}", ("chain = 'papr'", "did you mean 'paper'")),
    ("{chain: 3}", ("chain = ", "3")),
    ("{chain: paper, " + FAULTS + "}", ("link.faults", "chain: deployed")),
])
def test_a_bad_chain_is_one_line_naming_it(tmp_path, capsys, text, words):
    # Catches: an unknown chain running the default chain silently (or a traceback), a
    # message that names neither the key nor the value, and link faults in the paper's chain
    # ignored (there is no link to apply them to: the run would claim faults it never had).
    before = snapshot(tmp_path)
    status, stdout, stderr = run(capsys, "simulate", "--scenario-text", text,
                                 "--out", tmp_path / "out")
    assert_one_line_error(status, stdout, stderr, "simulate", *words)
    assert snapshot(tmp_path) == before


def test_the_chain_option_with_link_faults_names_both(tmp_path, capsys):
    # Catches: --chain paper overriding a scenario with link faults without a word (the
    # faults silently dropped), and a message that does not say which option conflicts.
    before = snapshot(tmp_path)
    status, stdout, stderr = run(capsys, "simulate", "--scenario-text", "{" + FAULTS + "}",
                                 "--chain", "paper", "--out", tmp_path / "out")
    assert_one_line_error(status, stdout, stderr, "simulate", "--chain paper", "link.faults")
    assert snapshot(tmp_path) == before
    status, _, stderr = run(capsys, "simulate", "--chain", "papr", "--out", tmp_path / "out")
    assert status == 2 and "--chain" in stderr and "'papr'" in stderr


@pytest.fixture
def records(monkeypatch):
    """Every SimulationRecord the simulate command makes, kept for the test."""
    made = []
    original = simulate_report.simulate

    def keep(*args, **kwargs):
        made.append(original(*args, **kwargs))
        return made[-1]

    monkeypatch.setattr(simulate_report, "simulate", keep)
    return made


@pytest.mark.parametrize("scenario_chain, option, expected", [
    ("", "paper", "paper"),                  # --chain paper over the default
    (", chain: paper", "deployed", "deployed"),   # --chain deployed over the scenario's
])
def test_the_chain_option_runs_that_chain(tmp_path, capsys, records, scenario_chain, option,
                                          expected):
    # Catches: --chain parsed but not applied (the scenario's chain runs), the paper's chain
    # still routed through the guard, and a report that does not say which chain ran.
    out = tmp_path / "out"
    status, stdout, stderr = run(capsys, "simulate", "--scenario-text", SHORT % scenario_chain,
                                 "--chain", option, "--duration", "2.0", "--out", out)
    assert status == 0, stderr
    (record,) = records
    assert record.scenario.chain == expected
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"]["chain"] == expected
    report = (out / "report.md").read_text().splitlines()
    if expected == "paper":
        assert record.guard is None and metrics["guard"] is None
        assert report[2].startswith("Chain: the paper's chain: ")
    else:
        assert record.guard is not None and record.guard.num_commands >= 5
        assert metrics["guard"]["commands"] == record.guard.num_commands
        assert report[2].startswith("Chain: the deployed chain: ")
