import pytest

from stillcap.files.table import number_cell


def test_a_cell_is_a_finite_number_or_names_where_it_is():
    assert number_cell(" 1.5 ", "t.csv: row 2, column x") == 1.5
    with pytest.raises(ValueError, match=r"^t\.csv: row 2, column x: 'abc' is not a number$"):
        number_cell("abc", "t.csv: row 2, column x")
    with pytest.raises(ValueError, match=r"^t\.csv: row 2, column x: 'inf' is not a finite number$"):
        number_cell("inf", "t.csv: row 2, column x")
