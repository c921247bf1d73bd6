"""Operational tools over ROS 2: the demo (``gpf-nav demo``), the soak run and the node-latency
benchmark."""
