import sys, json, hashlib
from pathlib import Path
import libsumo
from lmpc_bridge.sim import SumoSim
from lmpc_msgs_py.messages import Control
fam, out = sys.argv[1], sys.argv[2]
seeds = [int(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else list(range(0, 25)) + list(range(100, 125))
sim = SumoSim(work_dir=Path(out + "_work"))
res = {}
for seed in seeds:
    try:
        sim.reset(fam, seed)
    except Exception as e:
        res[seed] = "FAIL " + str(e); continue
    h = hashlib.sha1()
    for k in range(30):
        for v in sorted(libsumo.vehicle.getIDList()):
            if v == "ego": continue
            h.update(f"{v}{libsumo.vehicle.getPosition(v)}{libsumo.vehicle.getSpeed(v)}".encode())
        if sim.outcome != "running": break
        sim.step(Control(stamp_s=sim.time_s, seq=sim.step_index, accel_mps2=0.0, steer_rad=0.0, mode="baseline", solver_status="test", solve_time_ms=0.0))
    res[seed] = h.hexdigest()[:12] + " " + ",".join(sorted(libsumo.vehicle.getIDList()))
json.dump(res, open(out + ".json", "w"), indent=0)
