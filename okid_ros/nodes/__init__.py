"""The two ROS 2 nodes (rclpy) and the message <-> numpy conversions.

- :mod:`.arx_identifier_node`: ``okid_arx_identifier`` (console script ``arx_identifier``);
- :mod:`.modal_estimator_node`: ``okid_modal_estimator`` (console script ``modal_estimator``);
- :mod:`.conversions`: messages <-> numpy, also for rosbags-deserialized messages;
- :mod:`.common`: parameters, input topics, diagnostics, the entry point.

The nodes' logic lives in :mod:`okid_ros.service` (no rclpy).
"""

import os

# The numerical work is many small matrix products: BLAS worker threads only contend with the
# executor thread and with the other node (see okid_ros/cli.py). Set before numpy loads;
# honoured only if the user set nothing.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
