"""LanguageMPC SUMO bridge: scenario suite, libsumo stepping, ego dynamics, observations,
metrics and the in-process episode runner (logic modules; only bridge_node imports rclpy)."""
