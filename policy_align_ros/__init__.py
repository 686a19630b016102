"""policy_align_ros: learn potential-based policies from constrained motion (PolicyAlign)."""

__version__ = "0.1.0"
