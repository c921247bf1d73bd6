"""The ROS-free estimator: parameter tables, input validation, initialisation, the filter factory and
the engine that orders measurements and drives a filter (what a node or an offline replay runs). Never
imports rclpy or gpf_nav.ros."""
