# Copyright 2026 affordance_registration developers
# SPDX-License-Identifier: Apache-2.0
"""A fixed cloud on a topic for late joiners: the sensors of the station's demo and scan modes."""

from __future__ import annotations

from sensor_msgs.msg import PointCloud2

from .qos import LATCHED

__all__ = ["LatchedCloudPublisher"]

#: s between looks at the topic's subscriptions
SUBSCRIBER_CHECK_S = 0.2


class LatchedCloudPublisher:
    """Publishes ``msg`` on ``topic`` of ``node`` (reliable, transient-local), stamped now: at
    once, and again whenever a subscriber joins -- a volatile subscription, as the engine's and
    the station's, only hears what is published after it matched."""

    def __init__(self, node, msg: PointCloud2, topic: str = "points"):
        self.node, self.msg = node, msg
        self.pub = node.create_publisher(PointCloud2, topic, LATCHED)
        self._subscribers = 0
        self.publish()
        node.create_timer(SUBSCRIBER_CHECK_S, self._on_subscribers)

    @property
    def topic_name(self) -> str:
        return self.pub.topic_name

    def publish(self) -> None:
        self.msg.header.stamp = self.node.get_clock().now().to_msg()
        self.pub.publish(self.msg)

    def _on_subscribers(self) -> None:
        n = self.pub.get_subscription_count()
        if n > self._subscribers:
            self.publish()
        self._subscribers = n
