"""The ROS 2 side: the nodes, message conversions, launcher, bags and the browser station."""
