"""Clients of a ROS 2 graph that are not node executables (``call``, ``param``, ``demo``).

They create their own ``rclpy.Context`` and short-lived node, do one thing and shut down.
"""
