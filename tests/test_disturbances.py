"""The run summary's heading audit: the odometry's heading against the truth, unwrapped, split
into the periods when something touched or pushed the robot and the rest."""

from __future__ import annotations

import math

import pytest

from components.sim.runner.disturbances import HeadingAudit


def feed(audit: HeadingAudit, steps: list[tuple[float, float, tuple[str, ...]]],
         dt_s: float = 0.02) -> None:
    """Each step: (true heading change, odometry heading change, what touched) in degrees."""
    t = true = odo = 0.0
    audit.add(t_s=t, true_heading_rad=true, odometry_heading_rad=odo)
    for d_true, d_odo, touched in steps:
        t, true, odo = t + dt_s, true + math.radians(d_true), odo + math.radians(d_odo)
        audit.add(t_s=t, true_heading_rad=true, odometry_heading_rad=odo, touched=touched)


def test_an_error_past_half_a_turn_stays_visible() -> None:
    """2000° turned while the odometry reads 10 % more: 200° of error — wrapped into 0–180°
    it would read 160°, and a fraction under 10 % however long the run."""
    audit = HeadingAudit()
    feed(audit, [(2.0, 2.2, ())] * 1000)
    heading = audit.heading_summary()
    assert heading["turned_deg"] == pytest.approx(2000.0)
    assert heading["heading_error_deg"] == pytest.approx(200.0)
    assert heading["heading_error_fraction"] == pytest.approx(0.10)
    assert heading["undisturbed"] == pytest.approx(
        {k: heading[k] for k in ("heading_error_deg", "turned_deg", "heading_error_fraction")})
    assert audit.contacts_summary() == {"count": 0, "time_s": 0.0, "longest_s": 0.0, "by": {},
                                        "periods": []}


def test_contacts_and_pushes_are_reported_not_judged() -> None:
    """Turning 1 %-wrong in the open, then pinned against a box with the wheels still turning
    (odometry turns, the body does not), then shoved by a hand (the body turns, the wheels do
    not): the undisturbed error is the 1 %; the disturbed periods hold the rest."""
    audit = HeadingAudit()
    free = [(1.0, 1.01, ())] * 100              # 100° turned, 1° of error
    pinned = [(0.0, 2.0, ("obstacles[0]",))] * 50  # 100° of odometry, none true
    shoved = [(3.0, 0.0, ("push",))] * 10          # 30° true, none seen
    feed(audit, free + pinned + free + shoved + pinned[:1] + free)
    heading = audit.heading_summary()
    assert heading["undisturbed"]["turned_deg"] == pytest.approx(300.0)
    assert heading["undisturbed"]["heading_error_deg"] == pytest.approx(3.0)
    assert heading["undisturbed"]["heading_error_fraction"] == pytest.approx(0.01)
    assert heading["disturbed_heading_error_deg"] == pytest.approx(100.0 - 30.0 + 2.0)
    assert heading["turned_deg"] == pytest.approx(330.0)
    contacts = audit.contacts_summary()
    # The push and the one pinned step right after it are one period: touched without a break.
    assert contacts["count"] == 2
    assert [p["by"] for p in contacts["periods"]] == [["obstacles[0]"], ["obstacles[0]", "push"]]
    assert [(p["from_s"], p["to_s"]) for p in contacts["periods"]] == [
        pytest.approx((2.0, 3.0)), pytest.approx((5.0, 5.22))]
    assert contacts["time_s"] == pytest.approx(1.22)
    assert contacts["longest_s"] == pytest.approx(1.0)
    assert contacts["by"] == pytest.approx({"obstacles[0]": 1.02, "push": 0.2})


def test_no_turn_no_error_is_a_fraction_of_zero_and_the_list_is_bounded() -> None:
    audit = HeadingAudit(max_listed=3)
    feed(audit, [(0.0, 0.0, ()), (0.0, 0.0, ("arena",))] * 10)
    heading = audit.heading_summary()
    assert heading["heading_error_fraction"] == 0.0  # 0 ≤ 10 % of 0: the rule holds
    contacts = audit.contacts_summary()
    assert contacts["count"] == 10 and len(contacts["periods"]) == 3
    drift = HeadingAudit()
    feed(drift, [(0.0, 0.5, ())])
    assert drift.heading_summary()["heading_error_fraction"] is None  # an error over no turn
