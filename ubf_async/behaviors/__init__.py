"""Reusable behaviours. ``pink_ball`` holds the thesis's seek-the-pink-ball demonstration."""

from ubf_async.behaviors.pink_ball import (
    CAMERA_SOURCE,
    Chase,
    Flee,
    Search,
    pink_bins,
    seek_pink_ball,
)

__all__ = ["CAMERA_SOURCE", "Chase", "Flee", "Search", "pink_bins", "seek_pink_ball"]
