"""Robustness campaign: thousands of randomised physics stops on Dask, resumable, with a report.

* :mod:`drake_estop.campaign.config`: the sampled ranges (``default.yaml``) and per-run sampling.
* :mod:`drake_estop.campaign.executor`: the Dask executor (local cluster or ``--scheduler``), shared
  with ``drake-estop sweep``.
* :mod:`drake_estop.campaign.child`: the long-lived ``simulate`` process a worker runs its runs in
  (so that a hung run can be killed).
* :mod:`drake_estop.campaign.storage`: one parquet part per finished run, atomic, resumable.
* :mod:`drake_estop.campaign.runner`: one run, the error rows and :func:`run_campaign`.
* :mod:`drake_estop.campaign.report`: ``report.html`` and its figures.
"""
