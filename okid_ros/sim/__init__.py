"""Simulators with known truth: the paper's published model, modal structures with process
and measurement noise, the oracle Kalman predictor, scoring metrics and peer identifiers.

No rclpy.  Time along axis 0 (``u`` is (N, m), ``y`` is (N, p)); innovation form in the paper's
convention ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k``.
"""

from okid_ros.sim.systems import (  # noqa: F401
    BenchmarkCase,
    InnovationModel,
    NoisyStateSpace,
    benchmark_case,
    benchmark_cases,
    lowpass_input,
    modal_structure,
    propagate_states,
    simulate,
    simulate_innovation,
    simulate_noisy,
    white_input,
)
from okid_ros.sim.paper_model import paper_model, paper_modes  # noqa: F401
from okid_ros.sim.oracle import kalman_predictor, one_step_predictions  # noqa: F401

__all__ = [
    "BenchmarkCase", "InnovationModel", "NoisyStateSpace", "benchmark_case", "benchmark_cases",
    "lowpass_input", "modal_structure", "propagate_states", "simulate", "simulate_innovation",
    "simulate_noisy", "white_input", "paper_model", "paper_modes", "kalman_predictor",
    "one_step_predictions",
]
