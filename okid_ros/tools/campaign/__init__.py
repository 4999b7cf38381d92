"""A monitoring campaign: many bags processed as `okid-ros process` does, into one table.

Modules, one role each:

- :mod:`~okid_ros.tools.campaign.discovery`: find the bags under the paths given and read
  their plan (duration, topics, message counts) from the metadata or index only;
- :mod:`~okid_ros.tools.campaign.manifest`: what was already done (journal keyed by bag path,
  size, modification time and the parameters' hash) and atomic writes;
- :mod:`~okid_ros.tools.campaign.worker`: one bag, in any process: `process_bag` into a
  temporary folder, renamed into place when complete; failures become a one-line reason;
- :mod:`~okid_ros.tools.campaign.engines`: serial, a local process pool, or a Dask cluster;
- :mod:`~okid_ros.tools.campaign.table`: campaign mode ids (one deterministic pass after
  gathering) and the ``modes.parquet`` / ``summary.csv`` tables;
- :mod:`~okid_ros.tools.campaign.runner`: the command's orchestration and its summary;
- :mod:`~okid_ros.tools.campaign.moved`: a journaled bag given at a new path, its outputs and journal
  line moved with it;
- :mod:`~okid_ros.tools.campaign.forget`: bags taken out of a campaign (``--forget``);
- :mod:`~okid_ros.tools.campaign.lock`: one run at a time on a campaign directory, and the folders a
  killed run left;
- :mod:`~okid_ros.tools.campaign.plot`: frequency and damping of every mode id over the campaign.
"""

#: How long ``batch --scheduler`` tries to reach the cluster before giving up (Dask's own default
#: is 30 s); here, not in the engines, so the command line reads it without importing them.
SCHEDULER_TIMEOUT_S = 10.0
