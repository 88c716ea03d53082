"""lmpc_mpc."""
