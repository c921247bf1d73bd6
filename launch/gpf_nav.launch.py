"""Simulator + estimator on a ROS 2 system (needs launch and launch_ros; not installable from PyPI).

    ros2 launch gpf_nav gpf_nav.launch.py                      # real time, simulated clock
    ros2 launch gpf_nav gpf_nav.launch.py rate_factor:=20.0 filter:=spf
    ros2 launch gpf_nav gpf_nav.launch.py params_file:=/path/my_estimator.yaml namespace:=lander log_level:=debug
    ros2 launch gpf_nav gpf_nav.launch.py autostart:=false     # the estimator waits for a lifecycle manager
    ros2 launch gpf_nav gpf_nav.launch.py shutdown_on_simulator_exit:=true   # end with the trajectory
    ros2 launch gpf_nav gpf_nav.launch.py publish_suite:=true  # + altimeter, TRN fixes, velocimeter
    ros2 topic echo /odometry/filtered nav_msgs/msg/Odometry

The arguments, their choices and what they set are in ``gpf_nav.ros.launch_arguments`` (tested without
launch). ``use_sim_time``, ``autostart`` and ``filter`` override the params file only when given. A value
outside an argument's choices, a bad ``rate_factor`` or an unusable ``params_file`` stops the launch with
one message and a non-zero exit, before any node starts. Ctrl-C stops both nodes cleanly (exit 0).
Without launch_ros, ``gpf-nav demo`` runs the same pair in one process (docs/ros.md).
"""
import os
import shutil
import tempfile

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit, OnShutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from gpf_nav.ros import launch_arguments as args


def _nodes(context):
    """The two nodes, from the arguments' values (after launch has checked their choices)."""
    values = {a.name: LaunchConfiguration(a.name).perform(context) for a in args.ARGUMENTS}
    errors = args.check(values)
    if errors:
        raise RuntimeError("gpf_nav.launch.py: " + "; ".join(errors))
    common = dict(package="gpf_nav", output="screen", namespace=values["namespace"],
                  ros_arguments=["--log-level", values["log_level"]])
    config = os.path.join(get_package_share_directory("gpf_nav"), "config")
    simulator = Node(executable="simulator", name=args.SIMULATOR_NAME,
                     parameters=[os.path.join(config, "simulator.yaml"), args.simulator_parameters(values)],
                     **common)
    # params_file, then the given arguments in a file of their own (see gpf_nav.ros.launch_arguments),
    # in a folder removed when the launch ends
    folder = tempfile.mkdtemp(prefix="gpf_nav_launch_")
    files = args.estimator_parameter_files(values, folder)
    estimator = Node(executable="estimator", name=args.ESTIMATOR_NAME, parameters=files, **common)
    return [simulator, estimator,
            RegisterEventHandler(OnShutdown(on_shutdown=[OpaqueFunction(
                function=lambda _context: shutil.rmtree(folder, ignore_errors=True))])),
            RegisterEventHandler(OnProcessExit(target_action=simulator,
                                               on_exit=[Shutdown(reason="the simulator finished its trajectory")]),
                                 condition=IfCondition(values["shutdown_on_simulator_exit"]))]


def generate_launch_description():
    installed = os.path.join(get_package_share_directory("gpf_nav"), "config", "estimator.yaml")
    declared = [DeclareLaunchArgument(a.name, default_value=installed if a.default is None else a.default,
                                      description=a.description,
                                      **({"choices": list(a.choices)} if a.choices else {}))
                for a in args.ARGUMENTS]
    return LaunchDescription(declared + [OpaqueFunction(function=_nodes)])
