"""Reading RTD CSV files: header spellings, units, baseline, normalisation, one-line errors."""

import warnings

import numpy as np
import pytest

from fitting.data import Curve, DataError, DataWarning, read_many, read_rtd_csv


def _write(tmp_path, text, name="curve.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _gaussian_rows(times, centre=10.0, width=2.0, scale=3.0):
    return [(t, scale * np.exp(-((t - centre) ** 2) / (2 * width**2))) for t in times]


def _csv(header, rows, delimiter=","):
    lines = [header] if header is not None else []
    lines += [delimiter.join(f"{v:.12g}" for v in row) for row in rows]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("header", "unit"),
    [
        ("time_s,conc", "s"),
        ("t [min],c", "min"),
        ("time (s),concentration", "s"),
        ("t,E", "s"),
        ("Time (h),E(t) [1/h]", "h"),
        ("time_min,signal", "min"),
    ],
)
def test_header_spellings_and_time_units_are_recognised(tmp_path, header, unit):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    curve = read_rtd_csv(_write(tmp_path, _csv(header, rows)))
    assert curve.time_unit == unit
    np.testing.assert_allclose(curve.time, [r[0] for r in rows])


def test_normalised_curve_has_unit_trapezoid_area_and_keeps_its_shape(tmp_path):
    rows = _gaussian_rows(np.linspace(0, 30, 61), scale=7.0)
    path = _write(tmp_path, _csv("t,c", rows))
    curve = read_rtd_csv(path)
    raw = read_rtd_csv(path, normalise=False).value
    # Independent trapezoid sum, written out.
    area = np.sum(np.diff(curve.time) * (curve.value[1:] + curve.value[:-1]) / 2)
    assert area == pytest.approx(1.0, rel=1e-14)
    np.testing.assert_allclose(curve.value / curve.value.max(), raw / raw.max(), rtol=1e-12)


def test_raw_values_are_kept_without_normalisation(tmp_path):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    curve = read_rtd_csv(_write(tmp_path, _csv("t,c", rows)), normalise=False)
    np.testing.assert_allclose(curve.value, [r[1] for r in rows], rtol=1e-11)


@pytest.mark.parametrize("baseline", ["first", "min", 0.5])
def test_baseline_is_subtracted(tmp_path, baseline):
    rows = [(t, c + 0.5) for t, c in _gaussian_rows(np.linspace(0, 30, 31))]
    path = _write(tmp_path, _csv("t,c", rows))
    raw = read_rtd_csv(path, normalise=False, on_truncated="ignore").value
    offset = {"first": raw[0], "min": raw.min()}.get(baseline, baseline)
    curve = read_rtd_csv(path, baseline=baseline, normalise=False)
    np.testing.assert_allclose(curve.value, raw - offset, rtol=0, atol=1e-15)
    assert offset == pytest.approx(0.5, abs=1e-4)


def test_headerless_semicolon_and_whitespace_files_and_comments(tmp_path):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    semicolon = read_rtd_csv(_write(tmp_path, "# tracer run 3\n" + _csv(None, rows, ";"), "a.csv"))
    spaces = read_rtd_csv(_write(tmp_path, _csv("t c", rows, "   "), "b.csv"))
    np.testing.assert_allclose(semicolon.value, spaces.value)
    assert semicolon.name == "a" and semicolon.source.endswith("a.csv")


@pytest.mark.parametrize("rows_of_separators", [("", ";", ";;"), (",", ",,", " , ")],
                         ids=["semicolons", "commas"])
def test_rows_of_separators_alone_are_blank_rows_as_spreadsheets_save_them(
        tmp_path, rows_of_separators):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    delimiter = ";" if ";" in "".join(rows_of_separators) else ","
    lines = _csv("t [min];c".replace(";", delimiter), rows, delimiter).splitlines()
    empty = list(rows_of_separators)
    text = "\n".join([*lines[:10], empty[0], *lines[10:], *empty[1:]]) + "\n"
    curve = read_rtd_csv(_write(tmp_path, text))
    plain = read_rtd_csv(_write(tmp_path, "\n".join(lines) + "\n", "plain.csv"))
    np.testing.assert_array_equal(curve.time, plain.time)
    np.testing.assert_array_equal(curve.value, plain.value)
    # A row with a number and an empty cell is still a row with a missing value.
    with pytest.raises(DataError, match="empty cell"):
        read_rtd_csv(_write(tmp_path, text + f"31{delimiter}\n", "torn.csv"))


@pytest.mark.parametrize("separator", [";", ",", "\t"], ids=["semicolon", "comma", "tab"])
def test_a_spreadsheet_separator_line_names_the_cells_separator(tmp_path, separator):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    # A header with the other separators in its names: only the "sep=" line can tell.
    names = {";": "t [min];c, mg/L", ",": "t [min],c; mg/L", "\t": "t [min]\tc, mg/L; run 3"}
    text = _csv(names[separator], rows, separator)
    curve = read_rtd_csv(_write(tmp_path, f"sep={separator}\n" + text))
    assert curve.time_unit == "min"
    expected = np.array(rows)
    np.testing.assert_allclose(curve.time, expected[:, 0])
    plain = read_rtd_csv(_write(tmp_path, _csv(None, rows, separator), "plain.csv"))
    np.testing.assert_array_equal(curve.value, plain.value)


@pytest.mark.parametrize("header", ["time in min,c", "minutes,c", "Time hours,c"])
def test_a_time_unit_in_words_the_header_grammar_does_not_read_is_an_error(tmp_path, header):
    # Taken for seconds, such a curve's tau would be 60 or 3600 times too small.
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    with pytest.raises(DataError, match=r"curve.csv, row 1: the time column .* names its unit"):
        read_rtd_csv(_write(tmp_path, _csv(header, rows)))


def test_value_column_is_chosen_by_name_among_extra_columns(tmp_path):
    rows = [(t, c, 99.0) for t, c in _gaussian_rows(np.linspace(0, 30, 31))]
    path = _write(tmp_path, _csv("t,sample_id,temperature", rows))
    curve = read_rtd_csv(path, value_column="sample_id", normalise=False)
    np.testing.assert_allclose(curve.value, [r[1] for r in rows], rtol=1e-11)


def test_curve_is_immutable():
    curve = Curve("x", np.arange(3.0), np.ones(3))
    with pytest.raises(ValueError):
        curve.time[0] = 5.0
    with pytest.raises(AttributeError):
        curve.name = "y"


def test_read_many_reads_a_folder_in_name_order(tmp_path):
    rows = _gaussian_rows(np.linspace(0, 30, 31))
    for name in ("run2.csv", "run1.csv"):
        _write(tmp_path, _csv("t,c", rows), name)
    curves = read_many(tmp_path)
    assert [c.name for c in curves] == ["run1", "run2"]
    assert len(read_many([tmp_path / "run2.csv"])) == 1


def _good_rows():
    return _gaussian_rows(np.linspace(0, 30, 31))


BAD_FILES = {
    # name: (file text, row named in the message or None, words in the message)
    "missing column": ("t\n1\n2\n3\n4\n5\n6\n", 1, "missing column"),
    "extra columns": (_csv("t,a,b", [(1, 2, 3)] * 6), 1, "extra columns"),
    "no time column": (_csv("a,b,d", [(1, 2, 3)] * 6), 1, "missing time column"),
    "short row": ("t,c\n0,0\n1,1\n2\n3,1\n4,0\n5,0\n", 4, "missing columns"),
    "long row": ("t,c\n0,0\n1,1\n2,1,7\n3,1\n4,0\n5,0\n", 4, "extra columns"),
    "non-numeric": ("t,c\n0,0\n1,1\n2,abc\n3,1\n4,0\n5,0\n", 4, "non-numeric cell 'abc'"),
    "empty cell": ("t,c\n0,0\n1,1\n2,\n3,1\n4,0\n5,0\n", 4, "empty cell"),
    "nan": ("t,c\n0,0\n1,1\n2,nan\n3,1\n4,0\n5,0\n", 4, "NaN"),
    "negative value": ("t,c\n0,0\n1,1\n2,-0.5\n3,1\n4,0\n5,0\n", 4, "negative value"),
    "negative time": ("t,c\n-1,0\n1,1\n2,1\n3,1\n4,0\n5,0\n", 2, "negative time"),
    "times not increasing": ("t,c\n0,0\n1,1\n3,1\n3,1\n4,0\n5,0\n", 5, "times not increasing"),
    "too few points": ("t,c\n0,0\n1,1\n2,0\n", None, "too few points"),
    "all zero": ("t,c\n0,0\n1,0\n2,0\n3,0\n4,0\n5,0\n", None, "all-zero"),
    "empty file": ("# only a comment\n\n", None, "empty"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_file_gives_one_line_error_naming_file_row_and_problem(tmp_path, case):
    text, row, words = BAD_FILES[case]
    path = _write(tmp_path, text, "bad.csv")
    with pytest.raises(DataError) as caught:
        read_rtd_csv(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert words in message
    if row is not None:
        assert f"row {row}:" in message
    assert isinstance(caught.value, ValueError)


def test_missing_file_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match=r"nowhere\.csv: file not found$"):
        read_rtd_csv(tmp_path / "nowhere.csv")


def test_min_points_is_respected(tmp_path):
    path = _write(tmp_path, _csv("t,c", _good_rows()[:12]))
    with pytest.raises(DataError, match="12 data rows, at least 20 needed"):
        read_rtd_csv(path, min_points=20, on_truncated="ignore")


def test_curve_that_never_returns_to_baseline_warns_or_raises(tmp_path):
    rows = _gaussian_rows(np.linspace(0, 12, 13))  # cut off just after the peak at t = 10
    path = _write(tmp_path, _csv("t,c", rows))
    with pytest.warns(DataWarning, match="row 14: the curve never returns to baseline"):
        read_rtd_csv(path)
    with pytest.raises(DataError, match="row 14: the curve never returns to baseline"):
        read_rtd_csv(path, on_truncated="error")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_rtd_csv(path, on_truncated="ignore")
