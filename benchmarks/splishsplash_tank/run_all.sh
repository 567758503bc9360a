#!/bin/bash
# runs all scenes (sequentially, 2 OpenMP threads each)
cd "$(dirname "$0")"
export LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 OMP_NUM_THREADS=2
for c in ${@:-akinci_spec volmap_spec akinci_spec_dt5e-3 volmap_spec_dt5e-3 akinci_tuned volmap_tuned akinci_tuned_dt0.001 akinci_tuned_dt0.002 akinci_tuned_dt0.005 volmap_tuned_dt0.005 wcsph_akinci_tuned wcsph_akinci_tuned_dt5e-5 wcsph_volmap_tuned}; do
  case $c in *tuned*) export SY=1.0008514038524843;; *) export SY=1;; esac
  rm -rf out_$c
  ( time timeout 580 ~/sph-venv/bin/python run_tank.py tank2d_$c.json out_$c ) > out_$c.log 2>&1
  echo "$c rc=$?"
done
