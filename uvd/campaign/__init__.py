"""Campaigns (``uvd campaign SPEC.toml``): many lockstep experiments as one study on Dask.

:mod:`~uvd.campaign.spec` reads and checks a campaign file into the list of runs;
:mod:`~uvd.campaign.runs` is the run function of each kind (one lockstep experiment);
:mod:`~uvd.campaign.store` keeps each finished run as a row, keyed by the hash of its inputs and
the code version, so an interrupted campaign resumes; :mod:`~uvd.campaign.execute` hands the
runs to Dask (a ``LocalCluster`` or a scheduler's address) — the only scheduler;
:mod:`~uvd.campaign.summary` turns the rows into rates with confidence intervals and
:mod:`~uvd.campaign.report` draws them.
"""
