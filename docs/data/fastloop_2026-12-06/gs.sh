#!/bin/bash
# usage: gs.sh tag clock [extra]   (city_dense)
tag=$1; clk=$2; shift 2
D=/tmp/g/$tag; rm -rf $D; mkdir -p /tmp/g
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST timeout 400 /work/main/.venv/bin/python /work/main/scripts/run_graph.py --scene /work/main/examples/city_dense.yaml --planner rules --clock $clk --domain-id 72 --run-dir $D --summary-json $D.json "$@" > $D.log 2>&1
cd /tmp/g && /work/main/.venv/bin/python -c "
import json,sys
s=json.load(open('$tag.json'))
print('$tag', s.get('outcome'), s.get('sim_time_s'), 'start', round(s['startup_wall_s'],2), 'ep', round(s['episode_wall_s'],2), 'cyc', s['control_latency_ms'], 'solve', s['mpc_solve_ms'], 'att', s['mpc_attended_agents'], 'late', s['late_controls'])"
