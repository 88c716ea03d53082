"""QoS profiles of the graph. This module is about ROS itself, so it imports rclpy."""
from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

# Observations, decisions and controls: reliable, keep the last few. Reliable so
# that sync mode never loses a barrier message on loopback.
STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# The map is latched: late joiners get the last snapshot.
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# /clock as rclpy's own clock subscription expects it.
CLOCK = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# Visual mirrors (RViz, Foxglove): best effort is what those tools subscribe with by default
# for sensor-like data, but reliable publishers serve both kinds of subscriber.
MIRROR = STREAM
