"""Launch the policy_align_ros graph in a ROS 2 Jazzy workspace.

    ros2 launch policy_align_ros policy_align.launch.py [sim:=true] [demonstrator:=false]
        [use_sim_time:=false] [robot_config:=talos]

Starts ``recorder``, ``learner`` and ``executor`` with their parameter files from the
package's ``config/``; ``sim:=true`` adds ``sim_robot`` (a kinematic simulator in place
of the robot) and ``demonstrator:=true`` the scripted expert. ``use_sim_time:=true`` puts
every node on ``/clock``, which ``sim_robot`` then publishes (without ``sim``, your
simulator must). On a real robot leave
``sim`` false and remap ``/velocity_controller/commands`` to your forward command
controller's topic (and see the README on what to pair the executor with).
``robot_config`` (``talos``, ``panda``, ``ur5`` or a .yaml path) is every node's robot
config: robot, joints, controller and frames (``config/robots/``).

The executor's ``~/enable`` refuses until it has read the controller's joint order from
the node named by its ``controller`` parameter (``config/executor.yaml``). With
``sim:=true`` that node is ``sim_robot``: ``policy-align param set /executor controller
/sim_robot`` before enabling.
"""

from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from launch import LaunchDescription

PACKAGE = "policy_align_ros"
#: Always started; each executable reads ``config/<name>.yaml``.
CORE_NODES = ("recorder", "learner", "executor")
#: Started when the launch argument of the same name is true.
OPTIONAL_NODES = {"sim": "sim_robot", "demonstrator": "demonstrator"}


def _node(executable: str, condition=None) -> Node:
    params = PathJoinSubstitution([FindPackageShare(PACKAGE), "config", f"{executable}.yaml"])
    sim_time = {"use_sim_time": LaunchConfiguration("use_sim_time"),
                "robot_config": LaunchConfiguration("robot_config")}
    if executable == "sim_robot":
        # On simulated time the simulator is the source of /clock.
        sim_time["publish_clock"] = LaunchConfiguration("use_sim_time")
    return Node(
        package=PACKAGE,
        executable=executable,
        name=executable,
        parameters=[params, sim_time],
        output="screen",
        condition=condition,
    )


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("sim", default_value="false",
                              description="start sim_robot instead of a real robot"),
        DeclareLaunchArgument("demonstrator", default_value="false",
                              description="start the scripted expert"),
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="run every node on /clock (published by "
                                          "sim_robot with sim:=true)"),
        DeclareLaunchArgument("robot_config", default_value="talos",
                              description="every node's robot config: talos, panda, ur5 "
                                          "or a .yaml path"),
        *[_node(name) for name in CORE_NODES],
        *[_node(name, IfCondition(LaunchConfiguration(arg)))
          for arg, name in OPTIONAL_NODES.items()],
    ])
