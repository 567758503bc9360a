"""Parameter sweeps: a base scene plus varied keys, expanded into runs; each run is one
``simcli run`` in its own output folder, executed locally (``run-local``) or as one task of a
Slurm job array (``submit``).

- ``model``: the sweep file (pydantic), expansion (grid x zip), run names, per-run validation.
- ``tasks``: one task: run, resume from its checkpoint, or nothing if it is done; its state.
- ``slurm``: the sbatch script and its submission.
- ``cli``: the ``simcli sweep`` commands.
"""
