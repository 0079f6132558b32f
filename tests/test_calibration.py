"""docs/scenarios.md's calibration table is what the calibration script produces."""

from __future__ import annotations

import itertools
from pathlib import Path

from components.sim.render.calibrate import (
    CONTACT_M,
    DOC_BEGIN,
    DOC_END,
    calibration_table,
    markdown_table,
)

DOC = Path(__file__).resolve().parent.parent / "docs" / "scenarios.md"


def test_doc_table_is_generated_not_typed() -> None:
    text = DOC.read_text(encoding="utf-8")
    documented = text.split(DOC_BEGIN, 1)[1].split(DOC_END, 1)[0].strip()
    assert documented == markdown_table(calibration_table(seeds=8), seeds=8)


def test_thesis_thresholds_hold() -> None:
    rows = {round(r.distance_m, 2): r for r in calibration_table(seeds=8)}
    assert 120 <= rows[0.45].mean_total <= 160  # comfortable: chase and flee cancel near 140
    assert rows[0.35].mean_total > 140 > rows[0.60].mean_total
    assert rows[0.30].mean_total >= 180  # too close: flee wins, the robot backs away at −40
    assert rows[3.60].mean_max_bin >= 1  # still detectable at 360 cm
    # Closer than 30 cm flee keeps winning down to contact (the thesis: a ball kept close
    # makes the robot keep backing away).
    assert all(r.mean_total >= 180 and r.min_max_bin >= 100 for d, r in rows.items()
               if d <= 0.30)


def test_pink_count_never_grows_with_distance() -> None:
    """From contact to 3.6 m the count (largest bin and total, mean over seeds) does not
    increase with distance, beyond the frame-to-frame noise (the rows' min…max spread)."""
    rows = calibration_table(seeds=8)
    assert rows[0].distance_m == CONTACT_M and rows[-1].distance_m == 3.60
    for near, far in itertools.pairwise(rows):
        assert far.mean_max_bin <= near.mean_max_bin + 0.5 * (near.max_max_bin
                                                              - near.min_max_bin), (near, far)
        assert far.mean_total <= near.mean_total * 1.02 + 1, (near, far)
