"""Numbers in messages without an exponent: an engineer reads "60000 mm", not "6e+04 mm"."""

import pytest

from sim.text import figure, mm


@pytest.mark.parametrize("x, shown", [(60.0, "60000 mm"), (0.0123456, "12.3 mm"),
                                      (1.5, "1500 mm"), (4e-8, "0.00004 mm"),
                                      (0.0, "0 mm"), (-0.002, "-2 mm")])
def test_lengths_are_written_out_in_mm(x, shown):
    assert mm(x) == shown


def test_figures_keep_their_significant_digits():
    assert figure(2_000_000) == "2000000"
    assert figure(1234567, 4) == "1235000"
    assert figure(0.000123456) == "0.000123"
