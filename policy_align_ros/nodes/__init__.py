"""nodes subpackage of policy_align_ros."""
