"""Keep every lmpc-rules episode record of the development scenes per style (pickles in /tmp/recs):
    PYTHONPATH=<folder with lmpc_scripts -> scripts> .venv/bin/python dump_records.py rab,lane 100 125
(the work directory must not contain a comma: SUMO splits file options at it)."""
import pickle, sys
from lmpc_bridge.evaluation.scenes import SceneSpec
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts import methods
STYLES = (("c", "drive conservatively"), ("n", None), ("a", "drive aggressively"))
fams, lo, hi = sys.argv[1].split(","), int(sys.argv[2]), int(sys.argv[3])
sim = SumoSim(work_dir=f"/tmp/dump_{sys.argv[1].replace(',','_')}_{lo}")
for fam in fams:
    for seed in range(lo, hi):
        for style, text in STYLES:
            try:
                w = methods.build(SceneSpec("lmpc-rules", fam, seed, instruction=text))
                res = run_episode(sim, family=fam, seed=seed, controller=w.controller,
                                  planner=w.planner, max_time_s=200.0)
            except Exception as e:
                print(fam, seed, style, "ERR", e, flush=True); continue
            pickle.dump((res.record, res.metrics.time_s), open(f"/tmp/recs/{fam}_{seed}_{style}.pkl", "wb"))
        print(fam, seed, flush=True)
