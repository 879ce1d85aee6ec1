"""What labs export (issues 22 and 24): decimal commas, BOM and CRLF, a repeated header,
quoted numbers without a header; each failure says what it saw and which option helps."""

from __future__ import annotations

import pytest

from piezopress.errors import ImportFormatError
from piezopress.pipelines.importing import import_table

COLS = {"t_s": 1, "command_v": 2, "force_n": 3}
EU = "Zeit [s];Spannung [V];Kraft [N]\r\n" + "".join(
    f"{k * 0.001:.3f};{1.5 * k:.3f};{50 + 0.8 * k:.3f}\r\n".replace(".", ",") for k in range(200)
)


def write(tmp_path, name, text, bom=False):
    p = tmp_path / name
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    return p


@pytest.mark.parametrize("bom", [False, True])
def test_a_european_labview_style_export_is_read_with_its_decimal_comma(tmp_path, bom):
    run = import_table(write(tmp_path, "eu.csv", EU, bom), columns=COLS)
    assert len(run.data) == 200 and run.sample_rate_hz == pytest.approx(1000.0)
    assert run.data["command_v"].iloc[-1] == pytest.approx(1.5 * 199) and run.data["force_n"].iloc[1] == pytest.approx(
        50.8
    )
    assert run.meta["import"]["decimal"] == "comma"


def test_a_header_repeated_among_the_data_is_dropped_and_counted(tmp_path):
    lines = EU.splitlines(keepends=True)
    text = "".join(lines[:101] + [lines[0]] + lines[101:])
    run = import_table(write(tmp_path, "again.csv", text), columns=COLS)
    assert len(run.data) == 200 and run.meta["import"]["repeated_headers_dropped"] == 1


def test_a_decimal_comma_read_as_a_point_says_which_option_helps(tmp_path):
    with pytest.raises(ImportFormatError) as err:
        import_table(write(tmp_path, "eu.csv", EU), columns=COLS, decimal="point")
    msg = str(err.value)
    assert "'0,000'" in msg and "--decimal comma" in msg and "\n" not in msg


def test_a_decimal_comma_with_comma_separated_fields_is_refused_saying_why(tmp_path):
    with pytest.raises(ImportFormatError, match="--delimiter semicolon"):
        import_table(write(tmp_path, "c.csv", "0,1,2\n1,2,3\n"), columns=COLS, decimal="comma")


def test_all_quoted_numbers_without_a_header_lose_no_row(tmp_path):
    """Issue 24's data loss: the header guess took a quoted first row for a header."""
    text = "".join(f'"{k * 0.001:.6f}","{k:.6f}","{50 + k:.6f}"\n' for k in range(2000))
    run = import_table(write(tmp_path, "q.csv", text), columns=COLS)
    assert len(run.data) == 2000 and run.data["command_v"].iloc[0] == 0.0
