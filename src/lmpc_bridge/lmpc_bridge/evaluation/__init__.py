"""The evaluation library: running scenes of a method and summarising them (no ROS).

``rows``       the ``results.csv`` row: columns, error rows, latency cells, read / write
``scenes``     one scene in a worker process and the parallel runner (resume, interrupt)
``executors``  where the scenes run: the local process pool (default) or Ray tasks
``replay``     whether an ``lmpc-replay`` row repeats the recorded one
``table``      Table I: aggregation per family and method, and its Markdown
``decisions``  planner figures from the scenes' decision logs

The bridge imports neither the planner nor the MPC: a method's planner and controller
come from a factory the composition root (``scripts/methods.py``) passes in, typed by
the Protocols of ``lmpc_bridge.runner`` (docs/ARCHITECTURE.md, "Evaluation").
"""
