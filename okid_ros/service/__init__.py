"""The nodes' logic without rclpy, shared by the live nodes and the offline tools.

- :mod:`.sample_grid`: synchronized samples from per-topic channel updates (`SampleGrid`);
- :mod:`.inputs`: the input source specifications of the parameters (`parse_source`);
- :mod:`.params`: parameter declarations of both nodes (names, defaults, ranges, units) and
  the YAML loader the offline tools use;
- :mod:`.identification`: node 1, windowed ARX identification (`ArxIdentificationService`);
- :mod:`.estimation`: node 2, realization, mode tracking and the modal state estimator
  (`ModalEstimationService`).
"""
