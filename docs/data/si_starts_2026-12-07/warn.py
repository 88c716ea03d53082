import sys
from pathlib import Path
from lmpc_bridge.sim import SumoSim
for fam in sys.argv[1].split(","):
    sim = SumoSim(work_dir=Path(f"/tmp/sty/warn_{fam}"))
    for seed in list(range(0, 25)) + list(range(100, 125)):
        try:
            sim.reset(fam, seed)
            w = sim.traffic_warnings()
            if w: print("WARN", fam, seed, w, flush=True)
        except Exception as e:
            print("FAIL", fam, seed, e, flush=True)
    sim.close()
    print("done", fam, flush=True)
