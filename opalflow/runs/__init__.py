"""The run layer: the record of one run (``record.py``: run.json, summary.json and report.md, written
here only; their names are :mod:`opalflow.store`'s), how one run's LAMMPS is started (``launch.py``), where many runs go (``executors.py``:
local pool, Dask, SLURM job arrays), a study's jobs cached by spec hash (``jobs.py``), what a folder's
runs are doing (``status.py``) and what a workflow will cost (``plan.py``).  It imports no track."""
