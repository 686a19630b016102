"""Clients of a running ROS 2 graph that are not node executables (``call``, ``param``).

They create their own ``rclpy.Context`` and short-lived node, do one thing and shut down.
"""
