cd /work/main
for i in $(seq 1 40); do
  for v in prof none; do
    if [ $v = none ]; then export FASTRTPS_DEFAULT_PROFILES_FILE=/tmp/dds/empty.xml; else unset FASTRTPS_DEFAULT_PROFILES_FILE; fi
    bash docs/data/fastloop_2026-12-06/g.sh su_${v}_$i usi 0 sync >> /tmp/dds/gloop_$v.txt 2>&1
  done
done
echo done > /tmp/dds/gloop.done
