"""FEM.Cloth: thin shells (StVK membrane + discrete-shell bending), backward Euler by Newton on the
incremental potential, intersection-free contact by IPC barriers (ipctk for self-contact, signed-distance
point barriers for colliders and domain walls). Numpy/scipy on the host; see docs/FEM.md."""
