"""docs/scenarios.md's calibration table is what the calibration script produces."""

from __future__ import annotations

from pathlib import Path

from components.sim.calibrate import DOC_BEGIN, DOC_END, calibration_table, markdown_table

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
    assert rows[0.20].mean_total < 10  # below ≈30 cm the ball leaves the view
