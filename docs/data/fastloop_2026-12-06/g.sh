#!/bin/bash
# usage: g.sh tag scenario seed clock [extra]
tag=$1; sc=$2; seed=$3; clk=$4; shift 4
D=/tmp/g/$tag; rm -rf $D; mkdir -p /tmp/g
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST timeout 300 /work/main/.venv/bin/python /work/main/scripts/run_graph.py --scenario $sc --seed $seed --planner rules --clock $clk --domain-id 72 --run-dir $D --summary-json $D.json "$@" > $D.log 2>&1
/work/main/.venv/bin/python - $D.json <<'P'
import json,sys
s=json.load(open(sys.argv[1]))
print(sys.argv[1].split('/')[-1], s.get("outcome"), "start", round(s["startup_wall_s"],2), "ep", round(s["episode_wall_s"],2), "cycle", s["control_latency_ms"], "solve", s["mpc_solve_ms"], "att", s.get("mpc_attended_agents"), "cycle", s["profile_ms"]["bridge"]["step cycle (publish to publish)"]["median"], "oc", s["metrics"].get("overall_cost") if isinstance(s.get("metrics"), dict) else "")
P
