#!/bin/sh
# Builds examples/city.net.xml, the network of examples/city.yaml, with SUMO's netgenerate
# (from the eclipse-sumo wheel in .venv). Deterministic: the same seed gives the same ids.
set -e
cd "$(dirname "$0")"
NETGENERATE="${NETGENERATE:-../.venv/bin/netgenerate}"
"$NETGENERATE" --rand --rand.iterations 60 --seed 11 --default.lanenumber 2 \
    --rand.min-distance 60 --rand.max-distance 160 \
    --tls.guess true --tls.guess.threshold 30 --junctions.corner-detail 5 \
    --no-turnarounds true --no-warnings true -o city.net.xml
