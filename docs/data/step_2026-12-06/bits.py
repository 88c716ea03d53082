import hashlib, json, sys, time
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts.methods import build, SceneSpec
out = {}
t0 = time.perf_counter()
for method, fam, seed in [("lmpc-rules","usi",0),("lmpc-rules","si",3),("lmpc-rules","rab",1),("lmpc-rules","lane",2),("lmpc-rules","eoa",4),("mpc","usi",5),("lmpc-rules","usi",104)]:
    w = build(SceneSpec(method, fam, seed))
    res = run_episode(SumoSim(work_dir="/tmp/bitsw"), family=fam, seed=seed, controller=w.controller, planner=w.planner, max_time_s=200)
    rec = res.record if hasattr(res, "record") else res
    js = json.dumps([[s.step, s.x_m, s.y_m, s.yaw_rad, s.v_mps, s.control_accel_mps2, s.control_steer_rad, s.decision_id, s.control_mode] for s in rec.steps])
    out[f"{method}/{fam}/{seed}"] = hashlib.sha256(js.encode()).hexdigest()[:16]
print(json.dumps(out, indent=0)); print("wall", round(time.perf_counter()-t0,1), file=sys.stderr)
