# usage: trial.sh N domain
for i in $(seq 1 $1); do
  t=$(date +%s.%N)
  for x in a b c; do ROS_DOMAIN_ID=$2 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST /work/main/.venv/bin/python node.py $x $t & done
  wait
done
