#!/bin/bash
cd /work/main
for seed in 1 2 3; do
  scene=$(bench/rough_field.py /tmp/rough0/fields --seed $seed --origin 0,0,0)
  /tmp/rough0/isotrace watertight "$scene" --rays 10000000 --intersector isolation --ray-flow wavefront --offset 0,0,0 --threads 2 \
    --json /tmp/rough0/rough_$seed.json --dump /tmp/rough0/rough_$seed.failures.txt --dump-lost > /tmp/rough0/rough_$seed.txt 2>&1
  echo "seed $seed done rc=$?" >> /tmp/rough0/progress.txt
done
