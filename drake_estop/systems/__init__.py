"""Drake plumbing of the stop: the LeafSystems (pattern source, e-stop trigger, stop
planner), whole-body IK, the kinematic diagram and Meshcat."""
