"""Pictures of scenes, runs and benchmark results (matplotlib, Agg: files only; no ROS).

``runs``      a run to draw: read from its folder, written back, or run in this process
              (the method's planner and controller from a ``build`` factory), decision logs
``geometry``  lane surfaces, oriented boxes, junction outlines, picture windows (numpy)
``draw``      map, boxes, speed-coloured path and collision ring on matplotlib axes
``figures``   ``render_scene`` and ``render_run`` (path by speed plus key moments)
``gif``       ``render_gif``, the animated run
``bars``      ``plot_oc_bars``, the benchmark's O.C. per family and method
``multi``     a multi-ego run (issue 18): strip of instants and GIF, yielding ego marked

What is drawn and what is approximated (docs/PICTURES.md):

- Roads are the map's lane centerlines widened to the lane width (mitred
  offsets), junctions are the union of their internal lanes plus the junction
  outline from the SUMO net file when it is available. It is a drawing of the
  ``MapSnapshot``, not SUMO's own renderer.
- Other participants are oriented boxes at the recorded centre, heading and size
  (size from the record; records written before it carried sizes fall back to a
  typical size per kind). The record holds only participants within the ego's
  sensing range, so nobody further away appears.
- "Attended" (red) means: listed in the ``attention`` of the decision in force at
  that step (the step's ``decision_id``, i.e. the decision the MPC used). Runs
  without a planner have no decisions, so every participant is grey.

Only this package imports matplotlib: ``import lmpc_bridge`` stays free of it. Like the
rest of the bridge it imports neither the planner nor the MPC (``scripts/render.py``
passes the method registry's ``build`` to ``run_in_process``).
"""
import matplotlib

matplotlib.use("Agg")  # files only; never open a window (headless machines, workers)

from lmpc_bridge.render.bars import plot_oc_bars  # noqa: E402
from lmpc_bridge.render.figures import key_moments, render_run, render_scene  # noqa: E402
from lmpc_bridge.render.gif import MAX_GIF_BYTES, render_gif  # noqa: E402
from lmpc_bridge.render.multi import (  # noqa: E402
    MultiRunData,
    load_multi_run,
    multi_run_data,
    render_multi_gif,
    render_multi_strip,
)
from lmpc_bridge.render.runs import (  # noqa: E402
    DecisionInfo,
    RenderError,
    RunData,
    load_run,
    read_decision_log,
    run_in_process,
    save_run,
)

__all__ = ["MAX_GIF_BYTES", "DecisionInfo", "MultiRunData", "RenderError", "RunData",
           "key_moments", "load_multi_run", "load_run", "multi_run_data", "plot_oc_bars",
           "read_decision_log", "render_gif", "render_multi_gif", "render_multi_strip",
           "render_run", "render_scene", "run_in_process", "save_run"]
