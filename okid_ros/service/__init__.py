"""The nodes' logic without rclpy, shared by the live nodes and the offline tools.

- :mod:`.sample_grid`: synchronized samples from per-topic channel updates (`SampleGrid`), what
  it hands out in :mod:`.grid_samples` (`GridSample`, `GridCounters`), its sources' channels in
  :mod:`.grid_sources`;
  :mod:`.stamp_steps`: the rule for a stream's stamp steps (next, gap, duplicate, out of order);
- :mod:`.inputs`: the input source specifications of the parameters (`parse_source`);
- :mod:`.params`: the parameter table of both nodes (names, defaults, ranges, units, the
  service option each sets, whether it may change at run time) and the YAML loader the
  offline tools use; :mod:`.options`: the services' options derived from it;
- :mod:`.identification`: node 1, windowed ARX identification (`ArxIdentificationService`), its
  solve of a captured window in :mod:`.arx_solve` (`solve_capture`, `ArxSnapshot`);
- :mod:`.estimation`: node 2, the modal estimation service (`ModalEstimationService`), on its
  parts: :mod:`.arx_requests` (which ARX fits it refuses), :mod:`.realization_handoff` (the
  waiting request, the job in flight, the delivered outcome), :mod:`.realization` (realization and
  its checks), :mod:`.model_switch` (model switching, mode ids with :mod:`.mode_registry`),
  :mod:`.watch` (divergence and change watch), :mod:`.results` (what it hands out);
- :mod:`.windowed`: each node's step per sample, and both nodes in step offline
  (`WindowedPipeline`, ``okid-ros process``);
- :mod:`.records`: the one serialized shape of a mode, a change and a model update.
- :mod:`.tracked_record`: what ``okid-ros track`` names of a record before tracking it (missing
  samples, sensor faults).
"""
