"""``rover sim`` as an operator runs it: a range, a soak with a budget, one seed, and
the usage errors."""

from __future__ import annotations

import pytest

from sim.cli_sim import main


def test_a_range_of_seeds_says_its_figures_and_passes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--seeds", "0..15"]) == 0
    out = capsys.readouterr().out
    assert "rover sim: seeds 0..15" in out
    assert "16 scenarios" in out and "0 failed" in out
    assert "python: 8 scenarios" in out and "c: 8 scenarios" in out


def test_a_soak_runs_for_the_budget_it_is_given(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--budget", "0.5", "--start", "100", "--controller", "python"]) == 0
    out = capsys.readouterr().out
    assert "seeds from 100, for 0.5 s" in out
    assert "python:" in out and "c:" not in out


def test_one_seed_shows_the_scenario_and_its_trace(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--seed", "7", "--medium", "can", "--trace"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("seed 7: python controller on can")
    assert "status ready" in out and "passed:" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["--seed", "1", "--controller", "both"],
        ["--seeds", "5..2"],
        ["--tick-ms", "0.5", "--seed", "1"],
        ["--budget", "0"],
        ["--mutant", "no-such-mutant", "--seed", "1"],
    ],
)
def test_usage_errors_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code: object = main(argv)
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    assert code == 2
    assert "error" in capsys.readouterr().err
