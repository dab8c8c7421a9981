"""Tests for backend.optim.hessian_image (Hessian sparsity pattern rendering)."""

from __future__ import annotations

import io

import numpy as np
import pytest
import scipy.sparse
from PIL import Image

from backend.optim.hessian_image import (
    BACKGROUND_COLOR,
    GROUP_COLORS,
    MARGIN_PX,
    SEPARATOR_COLOR,
    SIDE_BY_SIDE_GAP_PX,
    ZERO_COLOR,
    HessianGroup,
    hessian_png_bytes,
    render_hessian,
    render_side_by_side,
    write_hessian_png,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def make_groups(*spec: tuple[str, int, int]) -> list[HessianGroup]:
    """Contiguous groups from (kind, size, items) triples."""
    groups, start = [], 0
    for kind, size, items in spec:
        groups.append(HessianGroup(kind=kind, start=start, size=size, items=items))  # type: ignore[arg-type]
        start += size
    return groups


def pixel(image: Image.Image, row: int, col: int) -> tuple[int, int, int]:
    """Colour at matrix pixel (row, col), matrix origin at (MARGIN_PX, MARGIN_PX) (no title)."""
    return image.getpixel((MARGIN_PX + col, MARGIN_PX + row))


# Small example: cameras 4 params | points 3 | lines 0 | planes 3, n = 10, scale 10 at max_px=100.
# Separators are inserted before params 4 and 7 (one pixel each).
SMALL_GROUPS = make_groups(("cameras", 4, 2), ("points", 3, 1), ("lines", 0, 0), ("planes", 3, 1))
SCALE = 10


def small_pixel_of(param: int) -> int:
    """Pixel offset (inside the matrix) of the centre of parameter `param` in the small example."""
    separators_before = int(param >= 4) + int(param >= 7)
    return param * SCALE + separators_before + SCALE // 2


def small_pattern() -> np.ndarray:
    H = np.zeros((10, 10))
    H[0:4, 0:4] = 1.0  # camera diagonal block
    H[7:10, 7:10] = 2.0  # plane diagonal block
    H[0:4, 7:10] = H[7:10, 0:4] = -0.5  # camera-plane coupling
    H[0, 4] = H[4, 0] = 3.0  # one camera-point entry
    # points diagonal block and points-planes block stay zero
    return H


def is_green(c: tuple[int, int, int]) -> bool:
    return c[1] > c[0] + 50 and c[1] > c[2] + 50


def is_blue(c: tuple[int, int, int]) -> bool:
    return c[2] > c[0] + 50 and c[2] > c[1] + 50


def is_orange(c: tuple[int, int, int]) -> bool:
    return c[0] > 200 and 80 < c[1] < 200 and c[2] < 80


def test_group_colours_are_what_the_paper_uses() -> None:
    assert is_green(GROUP_COLORS["cameras"])
    assert is_orange(GROUP_COLORS["points"]) and is_orange(GROUP_COLORS["lines"])
    assert is_blue(GROUP_COLORS["planes"])
    assert ZERO_COLOR == (0, 0, 0)


def test_pixel_colours_at_known_positions() -> None:
    image = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100, legend=False)
    p = small_pixel_of
    # camera diagonal block: green
    assert pixel(image, p(1), p(2)) == GROUP_COLORS["cameras"]
    assert is_green(pixel(image, p(3), p(0)))
    # plane diagonal block: blue
    assert pixel(image, p(8), p(9)) == GROUP_COLORS["planes"]
    # zero blocks: black (points diagonal, points-planes, most of camera-points)
    assert pixel(image, p(5), p(5)) == ZERO_COLOR
    assert pixel(image, p(5), p(8)) == ZERO_COLOR
    assert pixel(image, p(2), p(6)) == ZERO_COLOR
    # off-diagonal blocks take the later group's colour, on both sides of the diagonal
    assert pixel(image, p(1), p(8)) == GROUP_COLORS["planes"]
    assert pixel(image, p(8), p(1)) == GROUP_COLORS["planes"]
    assert pixel(image, p(0), p(4)) == GROUP_COLORS["points"]
    assert pixel(image, p(4), p(0)) == GROUP_COLORS["points"]
    # every pixel of a parameter's square has the same colour (nearest neighbour, no blur)
    corner = MARGIN_PX  # parameter 0 spans matrix pixels [0, 10)
    block = np.asarray(image)[corner : corner + SCALE, corner : corner + SCALE]
    assert (block == GROUP_COLORS["cameras"]).all()


def test_separators_are_inserted_at_group_boundaries() -> None:
    image = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100, legend=False)
    # matrix: 10 params * 10 px + 2 separators (cameras|points, points|planes; empty lines adds none)
    assert image.size == (2 * MARGIN_PX + 102, 2 * MARGIN_PX + 102)
    for boundary in (40, 40 + 1 + 30):
        assert pixel(image, 5, boundary) == SEPARATOR_COLOR  # vertical line
        assert pixel(image, boundary, 5) == SEPARATOR_COLOR  # horizontal line
    # the separator does not cover data: the last camera column and first point column
    assert pixel(image, 5, 39) == GROUP_COLORS["cameras"]
    assert pixel(image, 5, 41) == GROUP_COLORS["points"]  # H[0, 4] != 0


def test_only_palette_colours_inside_matrix() -> None:
    image = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100, legend=False)
    side = 102
    matrix = np.asarray(image)[MARGIN_PX : MARGIN_PX + side, MARGIN_PX : MARGIN_PX + side].reshape(-1, 3)
    colours = {tuple(int(v) for v in c) for c in np.unique(matrix, axis=0)}
    allowed = {ZERO_COLOR, SEPARATOR_COLOR, *GROUP_COLORS.values()}
    assert colours <= allowed
    assert GROUP_COLORS["cameras"] in colours and GROUP_COLORS["planes"] in colours


def test_symmetric_pattern_gives_symmetric_picture() -> None:
    image = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100, legend=False)
    side = 102
    matrix = np.asarray(image)[MARGIN_PX : MARGIN_PX + side, MARGIN_PX : MARGIN_PX + side]
    assert np.array_equal(matrix, matrix.transpose(1, 0, 2))


def test_sparse_and_dense_inputs_agree_and_explicit_zeros_are_ignored() -> None:
    dense = small_pattern()
    rows, cols = np.nonzero(dense)
    # store an explicit zero in the (otherwise empty) points diagonal block
    rows, cols = np.append(rows, 5), np.append(cols, 5)
    values = np.append(dense[np.nonzero(dense)], 0.0)
    sparse = scipy.sparse.coo_matrix((values, (rows, cols)), shape=dense.shape).tocsr()
    assert sparse.nnz == np.count_nonzero(dense) + 1  # the zero is stored
    assert sparse.has_canonical_format
    from_dense = render_hessian(dense, SMALL_GROUPS, max_px=100, legend=False)
    from_sparse = render_hessian(sparse, SMALL_GROUPS, max_px=100, legend=False)
    assert np.array_equal(np.asarray(from_dense), np.asarray(from_sparse))
    assert pixel(from_sparse, small_pixel_of(5), small_pixel_of(5)) == ZERO_COLOR


def test_coo_duplicates_are_summed_before_checking_for_zero() -> None:
    groups = make_groups(("cameras", 2, 1), ("planes", 2, 1))
    # (0, 0) stored twice with values cancelling to zero; (3, 3) stored twice summing to 2
    coo = scipy.sparse.coo_array(([1.0, -1.0, 1.0, 1.0], ([0, 0, 3, 3], [0, 0, 3, 3])), shape=(4, 4))
    image = render_hessian(coo, groups, max_px=40, legend=False)
    scale = 10
    assert pixel(image, 5, 5) == ZERO_COLOR
    assert pixel(image, 3 * scale + 1 + 5, 3 * scale + 1 + 5) == GROUP_COLORS["planes"]
    # the array API (sparray) and a csc matrix work as well
    csc = scipy.sparse.csc_matrix(coo)
    assert np.array_equal(np.asarray(render_hessian(csc, groups, max_px=40, legend=False)), np.asarray(image))


def test_png_bytes_decode() -> None:
    data = hessian_png_bytes(small_pattern(), SMALL_GROUPS, max_px=100, title="small")
    assert data.startswith(PNG_SIGNATURE)
    expected = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100, title="small")
    with Image.open(io.BytesIO(data)) as decoded:
        assert decoded.format == "PNG"
        assert decoded.size == expected.size
        assert np.array_equal(np.asarray(decoded.convert("RGB")), np.asarray(expected))  # lossless


def test_write_png_file(tmp_path) -> None:
    path = tmp_path / "hessian.png"
    write_hessian_png(path, small_pattern(), SMALL_GROUPS, max_px=50)
    assert path.read_bytes() == hessian_png_bytes(small_pattern(), SMALL_GROUPS, max_px=50)
    as_str = tmp_path / "as_str.png"
    write_hessian_png(str(as_str), small_pattern(), SMALL_GROUPS, max_px=50, legend=False)
    with Image.open(as_str) as decoded:
        assert decoded.format == "PNG"
        assert decoded.size == render_hessian(small_pattern(), SMALL_GROUPS, max_px=50, legend=False).size


def test_downsampling_keeps_an_isolated_nonzero() -> None:
    n_cam, n_pts = 3000, 2000
    groups = make_groups(("cameras", n_cam, 500), ("points", n_pts, 666))
    n, max_px = n_cam + n_pts, 100
    row, col = 1234, 4321  # a single camera-point entry
    sparse = scipy.sparse.csr_array(([1e-9], ([row], [col])), shape=(n, n))
    image = render_hessian(sparse, groups, max_px=max_px, legend=False)
    side = image.width - 2 * MARGIN_PX
    assert max_px <= side <= max_px + 1  # downsampled to ~max_px (+1 separator)
    matrix = np.asarray(image)[MARGIN_PX : MARGIN_PX + side, MARGIN_PX : MARGIN_PX + side]
    coloured = np.argwhere((matrix != ZERO_COLOR).any(-1) & (matrix != SEPARATOR_COLOR).any(-1))
    assert len(coloured) == 1  # exactly one (max pooled) pixel
    r, c = coloured[0]
    assert tuple(matrix[r, c]) == GROUP_COLORS["points"]  # later group wins
    assert abs(r - row * max_px / n) <= 1
    assert abs(c - (col * max_px / n + 1)) <= 1  # +1: cameras|points separator
    # dense input gives the same picture
    dense = np.zeros((n, n), dtype=np.float32)
    dense[row, col] = 1e-9
    assert np.array_equal(np.asarray(render_hessian(dense, groups, max_px=max_px, legend=False)), np.asarray(image))


def test_downsampling_gives_each_small_group_its_own_pixels() -> None:
    # 3 plane params among 5003: the plane block must still get its own (blue) pixel.
    groups = make_groups(("cameras", 5000, 100), ("planes", 3, 1))
    n = 5003
    sparse = scipy.sparse.csr_array(([1.0], ([5001], [5002])), shape=(n, n))
    image = render_hessian(sparse, groups, max_px=50, legend=False)
    side = image.width - 2 * MARGIN_PX
    matrix = np.asarray(image)[MARGIN_PX : MARGIN_PX + side, MARGIN_PX : MARGIN_PX + side]
    assert tuple(matrix[-1, -1]) == GROUP_COLORS["planes"]
    assert tuple(matrix[-2, -2]) == SEPARATOR_COLOR
    assert not (matrix[:-2, :-2] != 0).any()  # camera block all black


def test_two_by_two_groups_image_size() -> None:
    groups = make_groups(("cameras", 2, 1), ("planes", 2, 1))
    pattern = np.eye(4)
    # n = 4 < max_px = 10: scale 10 // 4 = 2, matrix 4 * 2 + 1 separator = 9 px
    image = render_hessian(pattern, groups, max_px=10, legend=False)
    assert image.size == (2 * MARGIN_PX + 9, 2 * MARGIN_PX + 9)
    big = render_hessian(pattern, groups, max_px=800, legend=False)
    assert big.size == (2 * MARGIN_PX + 801, 2 * MARGIN_PX + 801)
    assert pixel(big, 0, 0) == GROUP_COLORS["cameras"] and pixel(big, 799, 399) == ZERO_COLOR
    assert pixel(big, 800, 800) == GROUP_COLORS["planes"]
    # legend and title only add height (the matrix is wider than the text here)
    titled = render_hessian(pattern, groups, max_px=800, legend=True, title="two groups")
    assert titled.width == big.width and titled.height > big.height


def test_empty_groups() -> None:
    groups = make_groups(("cameras", 0, 0), ("points", 3, 1), ("lines", 0, 0), ("planes", 3, 1), ("planes", 0, 0))
    pattern = np.ones((6, 6))
    image = render_hessian(pattern, groups, max_px=60, legend=True, title="empty groups")
    assert image.width >= 2 * MARGIN_PX + 61
    plain = render_hessian(pattern, groups, max_px=60, legend=False)
    assert plain.size == (2 * MARGIN_PX + 61, 2 * MARGIN_PX + 61)  # one separator only
    assert pixel(plain, 0, 0) == GROUP_COLORS["points"]
    assert pixel(plain, 0, 30) == SEPARATOR_COLOR
    assert pixel(plain, 60, 60) == GROUP_COLORS["planes"]
    # no green anywhere: the empty cameras group has no legend swatch
    assert not (np.asarray(image) == GROUP_COLORS["cameras"]).all(-1).any()
    # all groups empty (n = 0) still renders a legend
    nothing = render_hessian(np.zeros((0, 0)), make_groups(("cameras", 0, 0), ("planes", 0, 0)))
    assert nothing.width > 2 * MARGIN_PX and nothing.height > 2 * MARGIN_PX
    assert hessian_png_bytes(np.zeros((0, 0)), []).startswith(PNG_SIGNATURE)


def test_legend_has_one_line_per_nonempty_group() -> None:
    def legend_height(groups: list[HessianGroup]) -> int:
        n = sum(g.size for g in groups)
        pattern = np.eye(n)
        return render_hessian(pattern, groups, max_px=300, legend=True).height - render_hessian(pattern, groups, max_px=300, legend=False).height

    two = legend_height(make_groups(("cameras", 6, 1), ("points", 6, 2)))
    two_plus_empty = legend_height(make_groups(("cameras", 6, 1), ("points", 6, 2), ("planes", 0, 0)))
    three = legend_height(make_groups(("cameras", 6, 1), ("points", 6, 2), ("planes", 6, 2)))
    assert two > 0
    assert two_plus_empty == two
    assert three > two
    # the swatches are drawn in the legend area, below the matrix
    groups = make_groups(("cameras", 6, 1), ("planes", 6, 2))
    image = np.asarray(render_hessian(np.zeros((12, 12)), groups, max_px=300, legend=True))
    below = image[MARGIN_PX + 301 :]
    for kind in ("cameras", "planes"):
        assert (below == GROUP_COLORS[kind]).all(-1).sum() > 20
    assert not (image[: MARGIN_PX + 301] == GROUP_COLORS["cameras"]).all(-1).any()  # zero matrix


def test_side_by_side() -> None:
    red = Image.new("RGB", (50, 40), (255, 0, 0))
    blue = Image.new("RGB", (70, 60), (0, 0, 255))
    green = Image.new("RGB", (30, 20), (0, 255, 0))
    combined = render_side_by_side([red, blue, green], labels=["a", "b", "c"])
    assert combined.width == 50 + 70 + 30 + 2 * SIDE_BY_SIDE_GAP_PX
    band = combined.height - 60
    assert band > 0  # label band above the tallest image
    assert combined.getpixel((10, band + 5)) == (255, 0, 0)
    assert combined.getpixel((50 + SIDE_BY_SIDE_GAP_PX // 2, band + 5)) == BACKGROUND_COLOR  # gap
    assert combined.getpixel((50 + SIDE_BY_SIDE_GAP_PX + 10, band + 55)) == (0, 0, 255)
    assert combined.getpixel((120 + 2 * SIDE_BY_SIDE_GAP_PX + 5, band + 5)) == (0, 255, 0)
    assert combined.getpixel((120 + 2 * SIDE_BY_SIDE_GAP_PX + 5, band + 30)) == BACKGROUND_COLOR  # shorter
    # labels are drawn (dark text somewhere in the band)
    assert (np.asarray(combined)[:band].max(-1) < 100).any()
    # real renders
    a = render_hessian(small_pattern(), SMALL_GROUPS, max_px=100)
    b = render_hessian(small_pattern(), SMALL_GROUPS, max_px=200)
    assert render_side_by_side([a, b], labels=["A", "B"]).width == a.width + b.width + SIDE_BY_SIDE_GAP_PX
    with pytest.raises(ValueError):
        render_side_by_side([a, b], labels=["only one"])
    with pytest.raises(ValueError):
        render_side_by_side([], labels=[])


def test_invalid_input_is_rejected() -> None:
    with pytest.raises(ValueError):
        HessianGroup(kind="landmarks", start=0, size=3, items=1)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        HessianGroup(kind="points", start=0, size=-3, items=1)
    gap = [HessianGroup(kind="cameras", start=0, size=6, items=1), HessianGroup(kind="points", start=7, size=3, items=1)]
    with pytest.raises(ValueError):
        render_hessian(np.eye(10), gap)
    with pytest.raises(ValueError):
        render_hessian(np.eye(5), SMALL_GROUPS)  # groups cover 10 params
    with pytest.raises(ValueError):
        render_hessian(scipy.sparse.eye(5), SMALL_GROUPS)
    with pytest.raises(ValueError):
        render_hessian(small_pattern(), SMALL_GROUPS, max_px=0)
