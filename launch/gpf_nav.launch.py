"""Simulator + estimator on a ROS 2 system (needs launch and launch_ros; not installable from PyPI).

    ros2 launch gpf_nav gpf_nav.launch.py                      # real time, simulated clock
    ros2 launch gpf_nav gpf_nav.launch.py rate_factor:=20.0 filter:=spf
    ros2 launch gpf_nav gpf_nav.launch.py params_file:=/path/my_estimator.yaml namespace:=lander log_level:=debug
    ros2 launch gpf_nav gpf_nav.launch.py autostart:=false     # the estimator waits for a lifecycle manager
    ros2 launch gpf_nav gpf_nav.launch.py shutdown_on_simulator_exit:=true   # end with the trajectory
    ros2 launch gpf_nav gpf_nav.launch.py publish_suite:=true  # + altimeter, TRN fixes, velocimeter
    ros2 topic echo /odometry/filtered

Ctrl-C stops both nodes cleanly (exit 0). Without launch_ros, ``gpf-nav demo`` runs the same pair in
one process (docs/ros.md).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, RegisterEventHandler, Shutdown
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from gpf_nav.estimator.factory import FILTERS


def generate_launch_description():
    config = os.path.join(get_package_share_directory("gpf_nav"), "config")
    namespace, log_level = LaunchConfiguration("namespace"), LaunchConfiguration("log_level")
    simulator = Node(package="gpf_nav", executable="simulator", name="lunar_simulator", output="screen",
                     namespace=namespace, ros_arguments=["--log-level", log_level],
                     parameters=[os.path.join(config, "simulator.yaml"),
                                 {"rate_factor": LaunchConfiguration("rate_factor"), "publish_clock": True,
                                  "publish_suite": ParameterValue(LaunchConfiguration("publish_suite"), value_type=bool)}])
    estimator = Node(package="gpf_nav", executable="estimator", name="gpf_estimator", output="screen",
                     namespace=namespace, ros_arguments=["--log-level", log_level],
                     parameters=[LaunchConfiguration("params_file"),
                                 {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                                  "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool),
                                  "filter": LaunchConfiguration("filter")}])
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=os.path.join(config, "estimator.yaml"),
                              description="ROS 2 params file of the estimator (gpf_estimator: ros__parameters:)."),
        DeclareLaunchArgument("namespace", default_value="",
                              description="Namespace of both nodes (their topics are relative; /tf, /clock and "
                                          "/diagnostics stay global)."),
        DeclareLaunchArgument("use_sim_time", default_value="true",
                              description="Estimator clock: true follows the simulator's /clock; false the wall clock."),
        DeclareLaunchArgument("log_level", default_value="info",
                              description="Log level of both nodes: debug, info, warn, error or fatal."),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="true: the estimator configures and activates itself; false: it waits, "
                                          "unconfigured, for a lifecycle manager."),
        DeclareLaunchArgument("filter", default_value="gpf", description=" | ".join(FILTERS)),
        DeclareLaunchArgument("rate_factor", default_value="1.0",
                              description="Simulated seconds per wall second."),
        DeclareLaunchArgument("publish_suite", default_value="false",
                              description="true: the simulator also publishes measurements/altitude, "
                                          "measurements/position (TRN, 4 s late) and measurements/velocity."),
        DeclareLaunchArgument("shutdown_on_simulator_exit", default_value="false",
                              description="true: end the launch (and the estimator) when the simulator "
                                          "exits at the end of its trajectory; false: the estimator stays up."),
        simulator,
        estimator,
        RegisterEventHandler(
            OnProcessExit(target_action=simulator,
                          on_exit=[Shutdown(reason="the simulator finished its trajectory")]),
            condition=IfCondition(LaunchConfiguration("shutdown_on_simulator_exit"))),
    ])
