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

# What the nodes publish on those streams: the same, but the publisher keeps its last
# samples for a subscriber that asks for them (transient local). A recorder's subscription
# can be matched on its side a moment before the publisher has matched it, and a volatile
# publisher sends step 0's message to the readers it knows at that instant only; with this
# the late match still delivers it. Subscribers use STREAM (volatile): compatible, no
# history, so a restarted node never sees old observations or decisions.
# Depth 100: a reliable KEEP_LAST writer overwrites samples a slow reader has not yet
# acknowledged; at ~15x real time the recorder, busy opening its bag connections at
# step 0, lost the first 14 controls with depth 10 (CI, test_graph_record). Volatile
# subscribers (every node) get no history, so the depth only matters to recorders.
PRODUCED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# The MPC's subscription to decisions: like STREAM, but transient local, so a decision the
# planner published before the two processes had matched still arrives when they match.
# With a volatile reader it was lost: the planner and the MPC discover each other on their
# own, after the bridge has seen both, and under load the planner's first decision (made
# on step 0) went out before its writer knew the MPC's reader; the MPC's sync barrier
# gave up after 1 s and drove without a decision until the next one 2.5 s later (CI,
# test_graph_instruction: the aggressive driver took the exit lane at 0.6 s). A
# restarted MPC now gets the planner's last decisions too; the timing rule and the TTL
# decide whether one is still in force, as for any decision. The cost: a VOLATILE publisher
# of decisions does not match this reader (DDS: incompatible durability; rclpy warns on
# both sides). Publish decisions with PRODUCED, as every node of the graph does (and
# `ros2 topic pub --qos-durability transient_local` by hand).
DECISION_IN = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
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
MIRROR = PRODUCED
