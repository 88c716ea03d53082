"""lmpc_bridge."""
