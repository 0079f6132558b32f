"""Fused cameras: several cameras' seekcolor readings seen as one wide camera.

A robot with two cameras side by side (the thesis's "rodent", §5.2: ``camera/left`` and
``camera/right`` yawed so that their fields of view meet) runs the shipped ``search``,
``chase`` and ``flee`` unchanged when they read one source whose five bins span both views:
a robot file's ``controller: fuse: {camera/both: [camera/left, camera/right]}`` makes the
state hold ``camera/both``, built at each snapshot from the cameras' latest readings
(:class:`CameraFusion`). Nothing is published: the fused source is the state's view of
what the robot already knows, so it costs no message and adds no latency.

The cameras are named left to right, their lenses alike and their views adjacent (the
caller's promise: the fusion reads bins, not mounts). Their ``5 × N`` bins, in image order,
are summed ``N`` at a time into five (:func:`merge_bins`): with two 35° cameras yawed ±17.5°
each fused bin spans 14° of the 70° view, centres at +28°, +14°, 0°, −14°, −28°. The total is
the cameras' totals summed: the ball's pixel count still gives its distance, whichever camera
sees it (flee's threshold means what it meant for one camera of the same lens).

A fused reading is only as good as its worst part: absent while a camera has never been
heard, stale while any is stale (the behaviours then abstain, as with one camera), stamped
with the oldest camera's capture.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ubf_async.core.state import Reading
from ubf_async.wire.topics import CameraSeekcolor

__all__ = ["BIN_COUNT", "CameraFusion", "merge_bins"]

BIN_COUNT = 5
"""A seekcolor reading's bins (the wire's ``camera.seekcolor``), fused or not."""


def merge_bins(per_camera: Sequence[Sequence[int]]) -> tuple[int, ...]:
    """The five bins of one wide camera made of ``per_camera``'s bins, left camera first:
    their ``5 × N`` bins in image order summed ``N`` at a time. Raises :class:`ValueError`
    for no camera or a camera without five bins."""
    if not per_camera:
        raise ValueError("merge_bins needs at least one camera's bins")
    if any(len(bins) != BIN_COUNT for bins in per_camera):
        raise ValueError(f"each camera's bins must be {BIN_COUNT}, got "
                         f"{[len(bins) for bins in per_camera]}")
    joined = [count for bins in per_camera for count in bins]
    group = len(per_camera)
    return tuple(sum(joined[i:i + group]) for i in range(0, len(joined), group))


@dataclass(frozen=True, slots=True)
class CameraFusion:
    """The fused source ``name`` (``camera/both``) of the camera sources ``sources``, named
    left to right (module docstring). Raises :class:`ValueError` for fewer than two sources,
    a source named twice, or a name among its sources."""

    name: str
    sources: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.sources) < 2:
            raise ValueError(f"{self.name}: fuses at least two cameras, got {list(self.sources)}")
        if len(set(self.sources)) != len(self.sources):
            raise ValueError(f"{self.name}: a camera named twice in {list(self.sources)}")
        if self.name in self.sources:
            raise ValueError(f"{self.name}: cannot fuse itself")

    def reading(self, readings: Mapping[str, Reading]) -> Reading | None:
        """The fused reading of ``readings`` (a snapshot's, by source), or ``None`` while a
        camera has no reading or one that is not a seekcolor sample."""
        parts = [readings.get(source) for source in self.sources]
        values = [part.value if part is not None else None for part in parts]
        if not all(isinstance(value, CameraSeekcolor) for value in values):
            return None
        cameras = [v for v in values if isinstance(v, CameraSeekcolor)]
        present = [part for part in parts if part is not None]
        oldest = min(present, key=lambda part: part.stamp_ns)
        widths = [c.width for c in cameras]
        latencies = [c.latency_s for c in cameras if c.latency_s is not None]
        value = CameraSeekcolor(
            bins=merge_bins([c.bins for c in cameras]),
            total=sum(c.total for c in cameras),
            # The cameras' bearings are each in its own frame: no bearing of the whole.
            bearing_rad=None,
            latency_s=max(latencies) if latencies else None,
            width=sum(w for w in widths if w is not None) if None not in widths else None,
            height=cameras[0].height)
        # seq: rises whenever any camera's does (what a reader compares to see a new frame).
        return Reading(value=value, stamp_ns=oldest.stamp_ns,
                       seq=sum(part.seq for part in present), age_s=oldest.age_s,
                       stale=any(part.stale for part in present))

    def add_to(self, readings: dict[str, Reading]) -> None:
        """Put the fused reading into ``readings`` (a snapshot's, by source being built);
        nothing while it has none."""
        fused = self.reading(readings)
        if fused is not None:
            readings[self.name] = fused
