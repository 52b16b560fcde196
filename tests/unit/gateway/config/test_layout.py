"""``GridLayout``: where each stored channel index sits on the drawn grid, checked against
index grids written out by hand (row 0 is the top row as drawn, column 0 the left column)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config.layout import LAYOUT_ORDERS, LAYOUT_ORIGINS, GridLayout
from gateway.errors import ConfigError

Grid = list[list[int | None]]

# Expected drawn grids: GRID[r][c] is the channel index drawn at row r, column c.
# 2 rows x 3 columns (6 channels). Row-major fills along a row, column-major down a column
# (2 rows: 0,1 in column 0, 2,3 in column 1, 4,5 in column 2); the origin is where 0 sits and
# mirrors rows (bottom) and/or columns (right).
GRIDS_2X3: dict[tuple[str, str], Grid] = {
    ("top-left", "row-major"): [[0, 1, 2], [3, 4, 5]],
    ("top-right", "row-major"): [[2, 1, 0], [5, 4, 3]],
    ("bottom-left", "row-major"): [[3, 4, 5], [0, 1, 2]],
    ("bottom-right", "row-major"): [[5, 4, 3], [2, 1, 0]],
    ("top-left", "column-major"): [[0, 2, 4], [1, 3, 5]],
    ("top-right", "column-major"): [[4, 2, 0], [5, 3, 1]],
    ("bottom-left", "column-major"): [[1, 3, 5], [0, 2, 4]],
    ("bottom-right", "column-major"): [[5, 3, 1], [4, 2, 0]],
}
# 3 rows x 2 columns (6 channels); column-major: 0,1,2 down column 0, 3,4,5 down column 1.
GRIDS_3X2: dict[tuple[str, str], Grid] = {
    ("top-left", "row-major"): [[0, 1], [2, 3], [4, 5]],
    ("top-right", "row-major"): [[1, 0], [3, 2], [5, 4]],
    ("bottom-left", "row-major"): [[4, 5], [2, 3], [0, 1]],
    ("bottom-right", "row-major"): [[5, 4], [3, 2], [1, 0]],
    ("top-left", "column-major"): [[0, 3], [1, 4], [2, 5]],
    ("top-right", "column-major"): [[3, 0], [4, 1], [5, 2]],
    ("bottom-left", "column-major"): [[2, 5], [1, 4], [0, 3]],
    ("bottom-right", "column-major"): [[5, 2], [4, 1], [3, 0]],
}
# 10 channels, 4 columns: ceil(10 / 4) = 3 rows, two cells of the grid stay empty (None).
GRIDS_10X4: dict[tuple[str, str], Grid] = {
    ("top-left", "row-major"): [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, None, None]],
    # bottom-up rows: the first stored row is the bottom one, the short last row on top
    ("bottom-left", "row-major"): [[8, 9, None, None], [4, 5, 6, 7], [0, 1, 2, 3]],
    ("top-right", "row-major"): [[3, 2, 1, 0], [7, 6, 5, 4], [None, None, 9, 8]],
    # column-major with 3 rows: columns 0..2 full, column 3 holds only index 9
    ("top-left", "column-major"): [[0, 3, 6, 9], [1, 4, 7, None], [2, 5, 8, None]],
    ("bottom-right", "column-major"): [[None, 8, 5, 2], [None, 7, 4, 1], [9, 6, 3, 0]],
}


def drawn(layout: GridLayout) -> Grid:
    """The layout's grid as ``GRID[r][c]`` (None where no channel sits)."""
    grid: Grid = [[None] * layout.columns for _ in range(layout.rows)]
    for i in range(layout.n_channels):
        row, col = layout.cell(i)
        assert grid[row][col] is None, f"cell ({row}, {col}) holds {grid[row][col]} and {i}"
        grid[row][col] = i
    return grid


@pytest.mark.parametrize(("origin", "order"), list(GRIDS_2X3))
def test_two_rows_of_three_by_hand(origin: str, order: str) -> None:
    layout = GridLayout(6, 3, 5.0, 5.0, origin, order)
    assert layout.rows == 2
    assert drawn(layout) == GRIDS_2X3[(origin, order)]


@pytest.mark.parametrize(("origin", "order"), list(GRIDS_3X2))
def test_three_rows_of_two_by_hand(origin: str, order: str) -> None:
    layout = GridLayout(6, 2, 5.0, 5.0, origin, order)
    assert layout.rows == 3
    assert drawn(layout) == GRIDS_3X2[(origin, order)]


@pytest.mark.parametrize(("origin", "order"), list(GRIDS_10X4))
def test_ten_channels_on_four_columns_leave_two_cells_empty(origin: str, order: str) -> None:
    layout = GridLayout(10, 4, 1.0, 1.0, origin, order)
    assert layout.rows == 3
    assert drawn(layout) == GRIDS_10X4[(origin, order)]


def test_every_origin_and_order_is_in_the_hand_tables() -> None:
    combos = {(o, r) for o in LAYOUT_ORIGINS for r in LAYOUT_ORDERS}
    assert set(GRIDS_2X3) == combos and set(GRIDS_3X2) == combos
    assert len(combos) == 8


def test_positions_are_column_times_pitch_x_and_row_times_pitch_y() -> None:
    # 2 x 3, bottom-left, row-major: index 0 at the bottom-left cell (row 1, column 0),
    # index 5 at the top-right (row 0, column 2); pitch 4 mm along x, 2.5 mm along y
    layout = GridLayout(6, 3, 4.0, 2.5, "bottom-left", "row-major")
    assert layout.position_mm(0) == (0.0, 2.5)
    assert layout.position_mm(2) == (8.0, 2.5)
    assert layout.position_mm(3) == (0.0, 0.0)
    assert layout.position_mm(5) == (8.0, 0.0)
    # top-right, column-major: index 0 at the top-right cell (row 0, column 2)
    mirrored = GridLayout(6, 3, 4.0, 2.5, "top-right", "column-major")
    assert mirrored.position_mm(0) == (8.0, 0.0)
    assert mirrored.position_mm(1) == (8.0, 2.5)
    assert mirrored.position_mm(5) == (0.0, 2.5)
    assert all(isinstance(v, float) for v in mirrored.position_mm(3))


def test_rows_and_cell_area() -> None:
    assert GridLayout(36, 6, 5.0, 5.0).rows == 6
    assert GridLayout(37, 6, 5.0, 5.0).rows == 7  # one channel more starts a seventh row
    assert GridLayout(1, 1, 2.0, 3.0).rows == 1
    assert GridLayout(7, 7, 1.0, 1.0).rows == 1  # a single row
    assert GridLayout(7, 1, 1.0, 1.0).rows == 7  # a single column
    assert GridLayout(6, 3, 4.0, 2.5).cell_area_mm2 == 10.0  # 4 mm x 2.5 mm
    assert GridLayout(4, 2, 5.0, 5.0).cell_area_mm2 == 25.0


def test_single_row_and_single_column_orders_agree() -> None:
    # one row: row-major and column-major both go left to right (1 row -> index = column)
    for order in LAYOUT_ORDERS:
        assert [GridLayout(4, 4, 1.0, 1.0, "top-left", order).cell(i) for i in range(4)] == [
            (0, 0), (0, 1), (0, 2), (0, 3),
        ]  # fmt: skip
        assert [GridLayout(3, 1, 1.0, 1.0, "bottom-left", order).cell(i) for i in range(3)] == [
            (2, 0), (1, 0), (0, 0),
        ]  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 80),
    data=st.data(),
    origin=st.sampled_from(LAYOUT_ORIGINS),
    order=st.sampled_from(LAYOUT_ORDERS),
    pitch_x=st.floats(0.1, 50.0),
    pitch_y=st.floats(0.1, 50.0),
)
def test_cells_are_distinct_and_inside_the_grid(
    n: int, data: st.DataObject, origin: str, order: str, pitch_x: float, pitch_y: float
) -> None:
    columns = data.draw(st.integers(1, n))
    layout = GridLayout(n, columns, pitch_x, pitch_y, origin, order)
    cells = [layout.cell(i) for i in range(n)]
    assert len(set(cells)) == n
    assert all(0 <= r < layout.rows and 0 <= c < columns for r, c in cells)
    # fewer than a full row of cells stay empty
    assert 0 <= layout.rows * columns - n < columns
    if n % columns == 0:
        # a full grid: the positions are a permutation of every cell of the grid
        assert sorted(cells) == [(r, c) for r in range(layout.rows) for c in range(columns)]
    for i, (r, c) in enumerate(cells):
        assert layout.position_mm(i) == (c * pitch_x, r * pitch_y)


@settings(max_examples=100, deadline=None)
@given(rows=st.integers(1, 9), columns=st.integers(1, 9), order=st.sampled_from(LAYOUT_ORDERS))
def test_the_origins_are_mirror_images_of_top_left(rows: int, columns: int, order: str) -> None:
    n = rows * columns
    base = GridLayout(n, columns, 1.0, 1.0, "top-left", order)
    right = GridLayout(n, columns, 1.0, 1.0, "top-right", order)
    bottom = GridLayout(n, columns, 1.0, 1.0, "bottom-left", order)
    both = GridLayout(n, columns, 1.0, 1.0, "bottom-right", order)
    for i in range(n):
        r, c = base.cell(i)
        assert right.cell(i) == (r, columns - 1 - c)
        assert bottom.cell(i) == (rows - 1 - r, c)
        assert both.cell(i) == (rows - 1 - r, columns - 1 - c)


def test_describe() -> None:
    assert (
        GridLayout(6, 3, 5.0, 5.0).describe() == "2 x 3 grid, pitch 5 mm, row-major, index 0 at the top-left"
    )
    assert (
        GridLayout(36, 6, 5.0, 2.5, "bottom-left", "column-major").describe()
        == "6 x 6 grid, pitch 5 x 2.5 mm, column-major, index 0 at the bottom-left"
    )
    # a short last row still counts as a row: 10 channels on 4 columns are 3 rows
    assert GridLayout(10, 4, 1.0, 1.0, "top-right").describe().startswith("3 x 4 grid, pitch 1 mm,")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_channels": 0}, "layout: channels: 0 is out of range; allowed: 1 or more"),
        ({"n_channels": -3}, "layout: channels: -3 is out of range; allowed: 1 or more"),
        ({"n_channels": True}, "layout: channels: True is out of range; allowed: 1 or more"),
        ({"n_channels": 6.0}, "layout: channels: 6.0 is out of range; allowed: 1 or more"),
        ({"columns": 7}, "layout: columns: 7 is out of range; allowed: 1..6 (at most channels = 6)"),
        ({"columns": 0}, "layout: columns: 0 is out of range; allowed: 1..6 (at most channels = 6)"),
        ({"columns": True}, "layout: columns: True is out of range; allowed: 1..6"),
        ({"pitch_x_mm": 0.0}, "layout: pitch_x_mm: 0.0 is out of range; allowed: (0, 1000] mm"),
        ({"pitch_y_mm": -1.0}, "layout: pitch_y_mm: -1.0 is out of range; allowed: (0, 1000] mm"),
        ({"pitch_x_mm": 1000.5}, "layout: pitch_x_mm: 1000.5 is out of range; allowed: (0, 1000] mm"),
        ({"pitch_y_mm": float("nan")}, "layout: pitch_y_mm: nan is out of range"),
        ({"pitch_x_mm": False}, "layout: pitch_x_mm: False is out of range"),
        (
            {"origin": "top-centre"},
            "layout: origin: 'top-centre' is not allowed; allowed: top-left, top-right, bottom-left, "
            "bottom-right",
        ),
        ({"origin": "Top-Left"}, "layout: origin: 'Top-Left' is not allowed"),
        (
            {"order": "row_major"},
            "layout: order: 'row_major' is not allowed; allowed: row-major, column-major",
        ),
    ],
)
def test_refusals_name_the_field_the_value_and_the_allowed_range(
    kwargs: dict[str, object], message: str
) -> None:
    args: dict[str, object] = {"n_channels": 6, "columns": 3, "pitch_x_mm": 5.0, "pitch_y_mm": 5.0}
    args.update(kwargs)
    with pytest.raises(ConfigError) as err:
        GridLayout(**args)  # type: ignore[arg-type]
    assert message in str(err.value)


def test_the_limits_themselves_are_allowed() -> None:
    layout = GridLayout(1, 1, 1000.0, 1000, "bottom-right", "column-major")  # int pitch, top of range
    assert layout.cell(0) == (0, 0) and layout.position_mm(0) == (0.0, 0.0)
    assert GridLayout(6, 6, 1e-9, 1e-9).rows == 1  # columns = channels, a tiny pitch
    assert GridLayout(6, 1, 5.0, 5.0).rows == 6  # a single column


def test_an_index_outside_the_grid_is_refused() -> None:
    layout = GridLayout(6, 3, 1.0, 1.0)
    for index in (-1, 6):
        with pytest.raises(IndexError, match=rf"channel index {index} is outside 0\.\.5"):
            layout.cell(index)
