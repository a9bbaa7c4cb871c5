"""Campaigns: a grid of runs (scenarios x parameters x seeds x methods) executed in-process,
in local worker processes or on a Dask distributed cluster, streamed to a resumable table.

By concern:

* :mod:`~fgnav.campaign.spec`: the study file (``data/studies/*.toml``) read into a frozen,
  validated :class:`Study` (every key checked, unknown keys rejected);
* :mod:`~fgnav.campaign.tasks`: the kinds of run, one function per kind with its typed
  parameters and typed result columns;
* :mod:`~fgnav.campaign.storage`: the runs table ``runs.csv`` (typed columns, append + fsync,
  torn last line dropped);
* :mod:`~fgnav.campaign.runners`: in-process, process pool and Dask execution, resume;
* :mod:`~fgnav.campaign.reports`: each study's table and plot, with the bounds and reference
  figures of the study's ``[reference]`` table.

Runs are independent and deterministic: a run is a pure function of its parameters (the
noise seed among them), so 1 worker, N workers and a Dask cluster give the same numbers.
"""

from fgnav.campaign.reports import REPORTS
from fgnav.campaign.runners import (CampaignResult, execute_run, read_runs, run_campaign,
                                     write_report)
from fgnav.campaign.spec import RunSpec, Study, builtin_studies, load_study, study_runs
from fgnav.campaign.tasks import TASKS, TIMING_COLUMNS

__all__ = ["Study", "RunSpec", "CampaignResult", "load_study", "builtin_studies", "study_runs",
           "run_campaign", "read_runs", "execute_run", "write_report", "TASKS", "REPORTS", "TIMING_COLUMNS"]
