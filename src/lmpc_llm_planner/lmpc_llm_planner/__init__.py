"""lmpc_llm_planner: prompt generator, LLM backends, decision validation, planner core.

Logic modules (no ROS): ``config``, ``schema``, ``scene``, ``route``, ``prompt``,
``validation``, ``backends``, ``planner``, ``mock_script``, ``assembler``.
Node modules (rclpy): ``decision_node``, ``planner_node``, ``mock_llm_node``.
"""
