"""The depth-to-colour registration test against hand-made views with a known shift."""

from __future__ import annotations

import numpy as np

from r2s.diagnose.plots import edge_figure
from r2s.diagnose.report import _decision_lines
from r2s.diagnose.stats import edge_alignment as ea
from r2s.synth.depth_registration import turned_about_centre

BOXES = ((20, 30, 40, 70), (60, 90, 20, 50), (50, 80, 100, 140), (15, 45, 110, 130))
"""(row0, row1, col0, col1) of four objects standing 10 cm in front of the table."""


def _view(shift_xy=(0, 0), dilate_px: int = 0, edge_holes_px: int = 0):
    """(depth (H, W) m, masks (H, W) ids): a table 1 m away, four boxes at 0.9 m. The depth
    image is moved by ``shift_xy`` pixels (+x right, +y down) against the masks, each mask
    grows by ``dilate_px`` on every side (a segmenter's bleed), and the depth reads
    nothing within ``edge_holes_px`` outside each box."""
    h, w = 110, 160
    depth = np.full((h, w), 1.0)
    masks = np.zeros((h, w), dtype=np.int32)
    for k, (r0, r1, c0, c1) in enumerate(BOXES, start=1):
        if edge_holes_px:
            e = edge_holes_px
            depth[r0 - e:r1 + e, c0 - e:c1 + e] = np.nan
        depth[r0:r1, c0:c1] = 0.9
        d = dilate_px
        masks[r0 - d:r1 + d, c0 - d:c1 + d] = k
    dx, dy = shift_xy
    moved = np.full_like(depth, np.nan)
    src = depth[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)]
    moved[max(0, dy):max(0, dy) + src.shape[0], max(0, dx):max(0, dx) + src.shape[1]] = src
    return moved, masks


def test_edges_and_outlines_of_a_box():
    depth, masks = _view()
    edges = ea.near_edges(depth)
    # the box's own outermost pixels are the near side of the jump; the table's are not
    assert edges[20, 50] and edges[29, 50] and edges[25, 40] and edges[25, 69]
    assert not edges[19, 50] and not edges[25, 50] and not edges[25, 70]
    outline = ea.inner_outline(masks == 1)
    assert outline.sum() == 2 * (10 + 30) - 4


def test_a_shifted_depth_image_is_found_and_measured():
    for shift in ((3, 0), (-2, 2), (0, -4)):
        finding = ea.test_edge_alignment(*_view(shift))
        assert finding is not None and finding.structured, shift
        np.testing.assert_allclose(finding.shift_px, shift, atol=0.3)
        assert finding.agreement == 1.0
        assert all(np.allclose(p, shift, atol=0.5) for p in finding.peaks_px.values())
    assert edge_figure(finding, "shift")[:8] == b"\x89PNG\r\n\x1a\n"


def test_aligned_views_bleeding_masks_and_edge_holes_are_not_reported():
    for kwargs in ({}, {"dilate_px": 2}, {"edge_holes_px": 2}):
        finding = ea.test_edge_alignment(*_view(**kwargs))
        assert finding is not None and not finding.structured, kwargs
        assert max(abs(v) for v in finding.shift_px) < 0.5, kwargs


def test_a_shift_across_the_depth_holes_of_the_edges():
    finding = ea.test_edge_alignment(*_view((3, 0), edge_holes_px=2))
    assert finding.structured
    np.testing.assert_allclose(finding.shift_px, (3, 0), atol=0.5)


def test_below_the_threshold_or_with_too_few_objects():
    finding = ea.test_edge_alignment(*_view((1, 0)))
    assert abs(finding.shift_px[0] - 1.0) < 0.3 and not finding.structured  # 1 px < 1.5
    depth, masks = _view((3, 0))
    masks[masks >= 3] = 0
    assert ea.test_edge_alignment(depth, masks) is None


def test_the_report_names_the_pattern():
    finding = ea.test_edge_alignment(*_view((3, 0)))
    lines = _decision_lines({"decision": [], "chosen": [], "unexplained": finding.summary(),
                             "gravity": None, "ties": []})
    text = " ".join(lines)
    assert "Unexplained structured residual" in text
    assert "3.0 px right" in text and "misregistered" in text


def test_a_turned_depth_image_is_found_where_the_shifts_cancel():
    """Turned 2.5 deg, the boxes' edges move 1.5-3 px each way: no common shift, a turn."""
    for turn in (2.5, -2.5):
        depth, masks = _view()
        finding = ea.test_edge_alignment(turned_about_centre(depth, turn), masks)
        assert finding.structured and finding.turn_structured, turn
        assert abs(finding.turn_deg - turn) < 0.5, finding.turn_deg
        assert finding.turn_gain >= 1.3
        assert max(abs(v) for v in finding.shift_px) < ea.MIN_SHIFT_PX
        side = "clockwise" if turn > 0 else "counter-clockwise"
        assert f"turned {abs(finding.turn_deg):.1f} deg {side}" in finding.pattern
    assert edge_figure(finding, "turn")[:8] == b"\x89PNG\r\n\x1a\n"


def test_aligned_or_bleeding_masks_read_no_turn():
    for kwargs in ({}, {"dilate_px": 2}, {"edge_holes_px": 2}):
        finding = ea.test_edge_alignment(*_view(**kwargs))
        assert abs(finding.turn_deg) < 0.3 and not finding.turn_structured, kwargs
