"""What the vehicle software perceives through: the raw sensors, or the radars' object lists alone."""

from __future__ import annotations

from enum import StrEnum


class PerceptionMode(StrEnum):
    """The stack's perception chain; every report and ``metrics.json`` says which one ran.

    ``LIDAR_CAMERA_RADAR``: raw LiDAR sweeps, camera boxes and radar objects through the stack's own
    perception (ground, snow filter, clusters, curbs, late fusion, aUToTrack); the simulator casts the
    sweeps. ``RADAR_TRACKING``: the radars' object lists tracked alone (about four times cheaper; the
    safety sweeps and fleet runs use it). Neither reads ground truth.
    """

    LIDAR_CAMERA_RADAR = "lidar_camera_radar"
    RADAR_TRACKING = "radar_tracking"

    @property
    def needs_raw_sensors(self) -> bool:
        """Whether the simulator must cast LiDAR sweeps and run its camera detectors."""
        return self is PerceptionMode.LIDAR_CAMERA_RADAR
