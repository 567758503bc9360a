"""Probes: time series measured while the run goes (docs/SCENE_FORMAT.md section 5, `probes:`).

``config``: the scene models and validate-time checks (no Taichi); ``sampling``: the numpy sampling
functions; ``recorder``: what the runner calls (sampling every N steps, probes.csv, sim.h5 /probes).
"""
