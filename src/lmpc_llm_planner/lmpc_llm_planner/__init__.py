"""lmpc_llm_planner."""
