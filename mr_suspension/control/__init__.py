"""Semi-active control laws (pure numerics, shared by the simulator and the controller node)."""
