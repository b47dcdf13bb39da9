"""What a figure can reach: every IK solution of a target, reachability maps and base placement, workspace samples."""
