"""IR range-finder models and readings in components.range.ir."""

from __future__ import annotations

import math

import numpy as np
import pytest

from components.range.ir import (
    GP2Y0A02,
    GP2Y0A21,
    GP2Y0A41,
    IR_MODELS,
    IrModel,
    read_ir,
)

MODELS = [GP2Y0A41, GP2Y0A21, GP2Y0A02]


def test_models_match_the_thesis() -> None:
    assert (GP2Y0A41.min_range_m, GP2Y0A41.max_range_m) == (0.04, 0.30)
    assert (GP2Y0A21.min_range_m, GP2Y0A21.max_range_m) == (0.10, 0.80)
    assert (GP2Y0A02.min_range_m, GP2Y0A02.max_range_m) == (0.20, 1.50)
    assert IR_MODELS == {"ir-4-30": GP2Y0A41, "ir-10-80": GP2Y0A21, "ir-20-150": GP2Y0A02}


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_error_is_always_between_5_and_10_percent(model: IrModel) -> None:
    rng = np.random.default_rng(1234)
    # stay 12 % inside the limits so that clipping to the range never applies
    distances = np.linspace(model.min_range_m * 1.12, model.max_range_m / 1.12, 60)
    signs = set()
    for d in distances:
        for _ in range(20):
            reading = read_ir(model, float(d), rng=rng)
            assert reading.status == "ok"
            assert isinstance(reading.range_mm, int)
            deviation_mm = abs(reading.range_mm - d * 1000)
            # whole millimetres: allow half a millimetre of rounding either way
            assert 0.05 * d * 1000 - 0.5 <= deviation_mm <= 0.10 * d * 1000 + 0.5
            signs.add(reading.range_mm > d * 1000)
    assert signs == {True, False}  # readings both above and below the truth


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_out_of_range_is_a_status_not_a_number(model: IrModel) -> None:
    rng = np.random.default_rng(0)
    for far in (None, model.max_range_m + 0.001, model.max_range_m * 2, math.inf):
        reading = read_ir(model, far, rng=rng)
        assert reading.status == "too_far"
        assert reading.range_mm is None
    for near in (0.0, model.min_range_m - 0.001, model.min_range_m / 2):
        reading = read_ir(model, near, rng=rng)
        assert reading.status == "too_close"
        assert reading.range_mm is None


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_readings_at_the_limits_are_clipped_to_the_range(model: IrModel) -> None:
    rng = np.random.default_rng(99)
    lo_mm, hi_mm = round(model.min_range_m * 1000), round(model.max_range_m * 1000)
    at_min = [read_ir(model, model.min_range_m, rng=rng) for _ in range(50)]
    at_max = [read_ir(model, model.max_range_m, rng=rng) for _ in range(50)]
    for reading in at_min + at_max:
        assert reading.status == "ok"
        assert reading.range_mm is not None
        assert lo_mm <= reading.range_mm <= hi_mm
    assert any(r.range_mm == lo_mm for r in at_min)
    assert any(r.range_mm == hi_mm for r in at_max)


def test_seeded_generator_is_reproducible() -> None:
    a = [read_ir(GP2Y0A21, 0.5, rng=np.random.default_rng(5)) for _ in range(3)]
    b = [read_ir(GP2Y0A21, 0.5, rng=np.random.default_rng(5)) for _ in range(3)]
    assert a == b


def test_custom_error_fraction() -> None:
    rng = np.random.default_rng(3)
    exact = (0.0, 0.0)
    readings = {read_ir(GP2Y0A02, 1.0, rng=rng, error_fraction=exact).range_mm for _ in range(10)}
    assert readings == {1000}
    for _ in range(20):
        r = read_ir(GP2Y0A02, 1.0, rng=rng, error_fraction=(0.2, 0.2))
        assert r.range_mm in (800, 1200)


def test_bad_input_rejected() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="true_distance_m"):
        read_ir(GP2Y0A21, math.nan, rng=rng)
    with pytest.raises(ValueError, match="true_distance_m"):
        read_ir(GP2Y0A21, -0.1, rng=rng)
    with pytest.raises(ValueError, match="error_fraction"):
        read_ir(GP2Y0A21, 0.5, rng=rng, error_fraction=(0.1, 0.05))
    with pytest.raises(ValueError, match="min_range_m"):
        IrModel(name="bad", min_range_m=0.5, max_range_m=0.1)
    with pytest.raises(ValueError, match="name"):
        IrModel(name="", min_range_m=0.1, max_range_m=0.5)
