"""Campaigns: every target of a video over many attack windows and designs (section 8.2).

* :mod:`lesmc.campaign.plan`: windows, designs, the units of work and their keys;
* :mod:`lesmc.campaign.work`: one group of units on one unfolded model (runs on a worker);
* :mod:`lesmc.campaign.store`: ``results.jsonl``, appended row by row, crash-safe;
* :mod:`lesmc.campaign.run`: perception once per video, targets, Dask or serial execution;
* :mod:`lesmc.campaign.summary`: statistics, ``campaign.html`` and figures from the rows.

Dask is imported only by :func:`lesmc.campaign.run.execute`, when a cluster is used.
"""
