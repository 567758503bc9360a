"""Free rigid bodies (``rigid_bodies:``), two-way coupled with the families through the moving-collider
path (simcli.colliders.ColliderPoses): config.py (the scene keys), body.py (mass, inertia, state),
contact.py (walls and body-body), world.py (the substep integration and the registry), output.py
(sim.h5), checks.py (bad input)."""
