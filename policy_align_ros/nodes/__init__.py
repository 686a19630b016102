"""Thin ROS 2 nodes of policy_align_ros (the only subpackage that imports rclpy).

One module per executable, each with a ``main()`` console script:

* ``sim_robot`` - kinematic simulation (``/velocity_controller/commands`` -> ``/joint_states``);
* ``recorder`` - one rosbag2 bag per demonstration (``~/start_demo``, ``~/stop_demo``);
* ``demonstrator`` - the expert under random hand-plane constraints;
* ``learner`` - PolicyAlign on the recorded demonstrations (``~/learn``, ``~/model``);
* ``executor`` - drives the robot with the learnt policy under configured constraints.

The demo's orchestration (``policy-align demo``) and the clients ``call`` and ``param``
live in :mod:`policy_align_ros.client`. The logic lives in the ROS-free subpackages.
"""
