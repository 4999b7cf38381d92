"""Bags, replay, offline processing, the monitor and the plots.

One module per role:

- :mod:`.bagio`: the typestore with okid_msgs, reading any rosbag2 (sqlite3, MCAP) and writing
  new ones (never over an existing path), conversion of rclpy messages for the writer;
- :mod:`.simulate_bag`: the paper-like experiment recorded as a bag, with the truth in the
  bag metadata;
- :mod:`.replay`: publish a bag on live topics with its original timing (rclpy);
- :mod:`.process`: the nodes' service layer run offline over a bag, output bag and JSON lines
  (:mod:`.offline`: both nodes fed input messages; :mod:`.node_parameters`: both nodes'
  parameters as they read them);
- :mod:`.campaign`: many bags processed as `process` does (local pool or Dask), one table of modes;
- :mod:`.monitor`: the live terminal view of the modes;
- :mod:`.plots`: PNG figures like the paper's Figs 2-5, and modes over time;
- :mod:`.errors`: the exceptions, all one-line `okid-ros` errors.

Importing this package imports neither rclpy nor matplotlib.
"""
