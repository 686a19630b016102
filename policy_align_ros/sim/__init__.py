"""ROS-free simulation: the kinematic robot, expert potentials and demonstrations.

``simulator`` integrates joint velocity commands within the joint limits; ``experts``
holds known potential-based policies; ``demonstrations`` runs them under changing
constraints and keeps the ground truth; ``script`` is the demonstrator node's expert
(random starts, random planes, one command per control period).
"""
