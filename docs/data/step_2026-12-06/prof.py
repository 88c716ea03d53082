import cProfile, pstats, time, sys
from lmpc_bridge.runner import run_episode
from lmpc_bridge.sim import SumoSim
from lmpc_scripts.methods import build, SceneSpec
w = build(SceneSpec("lmpc-rules", "usi", 0))
ctl = w.controller
orig = ctl.solver.solve
tsolve=[0.0]
def timed(p):
    t=time.perf_counter(); r=orig(p); tsolve[0]+=time.perf_counter()-t; return r
ctl.solver.solve = timed
origc = ctl.compute
tc=[0.0]; n=[0]
def tcomp(*a, **k):
    t=time.perf_counter(); r=origc(*a, **k); tc[0]+=time.perf_counter()-t; n[0]+=1; return r
ctl.compute = tcomp
prof = len(sys.argv) > 1
pr = cProfile.Profile()
if prof: pr.enable()
res = run_episode(SumoSim(work_dir="/tmp/profw"), family="usi", seed=0, controller=ctl, planner=w.planner, max_time_s=200)
if prof: pr.disable()
print("steps", n[0], "compute ms/step", 1000*tc[0]/n[0], "solve", 1000*tsolve[0]/n[0], "setup", 1000*(tc[0]-tsolve[0])/n[0])
if prof:
    st = pstats.Stats(pr); st.sort_stats("tottime").print_stats(35) if sys.argv[1]=="t" else st.sort_stats("cumulative").print_stats("lmpc_mpc", 60)
