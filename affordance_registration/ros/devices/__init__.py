"""Input devices without ROS: the SpaceMouse HID driver (its ROS node is ``ros.nodes.spacemouse_node``)."""
