"""The stored copy of the paper's Table I: its averages over the sequences biasgt shares with it."""

from __future__ import annotations

import pytest

from training.evaluation.paper import (COMMON_SEQUENCES, PAPER_AVERAGE_4, PAPER_ROWS, PAPER_SEQUENCES, TABLE_I, paper_average,
                            paper_sequence)


def test_averages_over_the_three_shared_sequences():
    assert COMMON_SEQUENCES == ("MH_04", "V1_03", "V2_02")
    prmse, roe = paper_average("Ours (RNN)")
    assert prmse == pytest.approx(0.0558, abs=5e-5) and roe == pytest.approx(0.1708, abs=5e-5)
    prmse, roe = paper_average("Random Walk")
    assert prmse == pytest.approx(0.0718, abs=5e-5) and roe == pytest.approx(0.1684, abs=5e-5)


def test_the_copy_reproduces_the_papers_own_four_sequence_average():
    """The paper's Average row (over MH_02, MH_04, V1_03, V2_02), printed to 4 decimals; one printed cell
    (Direct Regression (RNN) PRMSE, 0.0510) is not the mean of its row (0.0518)."""
    assert set(PAPER_ROWS) == set(TABLE_I) == set(PAPER_AVERAGE_4)
    for row, (prmse, roe) in PAPER_AVERAGE_4.items():
        got = paper_average(row, PAPER_SEQUENCES)
        assert got[1] == pytest.approx(roe, abs=6e-5), row
        if row == "Direct Regression (RNN)":
            assert got[0] == pytest.approx(0.051775) and prmse == 0.0510
        else:
            assert got[0] == pytest.approx(prmse, abs=6e-5), row


def test_sequence_names_map_onto_the_papers():
    assert paper_sequence("MH_04_difficult") == "MH_04" and paper_sequence("V1_03_difficult") == "V1_03"
    assert paper_sequence("V2_02") == "V2_02" and paper_sequence("semi_V2_02_medium") is None
    assert paper_sequence("test0") is None
