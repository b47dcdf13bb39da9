"""The kinematic core: the tree, FK, Jacobians, configuration space, building chains."""
