"""The pipeline on a Slurm cluster: DVC stages as job arrays against one shared DVC cache.

    python -m abcgs.cluster submit --cluster-dir /shared/abcgs     # on the login node, in the repository
    python -m abcgs.cluster status                                  # per-job state, the failing stage's log
    python -m abcgs.cluster collect                                 # dvc repro here: restores every stage

- :mod:`abcgs.cluster.plan`: ``dvc.yaml`` + params → jobs (a pure function): a prep job, one job per scene
  (its stages and colour matches), one per experiment after its scene's job, and the report after all.
- :mod:`abcgs.cluster.slurm`: the sbatch template, submission with ``--dependency``, job states.
- :mod:`abcgs.cluster.job`: one array task: a clone of the commit, ``dvc repro`` of the job's stages against the
  shared cache, its progress in the run folder (:mod:`abcgs.cluster.run`).
- :mod:`abcgs.cluster.dvc_run`: ``dvc`` that keeps every finished stage in the run cache.
- :mod:`abcgs.cluster.commands`: the commands above.

The package submits to a Slurm that is there; it installs and starts nothing on the host. A one-node Slurm on
localhost, for a try on one machine, the tests and the benchmark, comes from ``python -m eval.slurm_local`` in the
checkout (:data:`abcgs.cluster.slurm.LOCAL_SLURM_HINT`).

docs/SCALING.md "A Slurm cluster" describes the whole flow.
"""
