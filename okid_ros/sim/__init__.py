"""Simulators with known truth, and what the benchmarks score them with.

The paper's published model, modal structures with process and measurement noise, the oracle
Kalman predictor, scoring metrics and peer identifiers.

One role per module, imported in one direction (no cycle):

    models       system types (``InnovationModel`` of the core, ``NoisyStateSpace``), modal structures
    inputs       white and low-passed input sequences
    simulators   simulation of either kind of true system
    oracle       the oracle Kalman predictor and one-step predictions
    paper_model  the model published by Chen, Huang & Juang (1991)
    cases        the named benchmark cases
    scoring, switching, peers   benchmark scoring, the piecewise-constant simulator, peer methods

No rclpy.  Time along axis 0 (``u`` is (N, m), ``y`` is (N, p)); innovation form in the paper's
convention ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k``.
"""

from okid_ros.sim.cases import BenchmarkCase, benchmark_case, benchmark_cases
from okid_ros.sim.inputs import lowpass_input, white_input
from okid_ros.sim.models import InnovationModel, NoisyStateSpace, modal_structure
from okid_ros.sim.oracle import kalman_predictor, one_step_predictions
from okid_ros.sim.paper_model import paper_model, paper_modes
from okid_ros.sim.simulators import propagate_states, simulate, simulate_innovation, simulate_noisy

__all__ = [
    "BenchmarkCase", "InnovationModel", "NoisyStateSpace", "benchmark_case", "benchmark_cases",
    "lowpass_input", "modal_structure", "propagate_states", "simulate", "simulate_innovation",
    "simulate_noisy", "white_input", "paper_model", "paper_modes", "kalman_predictor",
    "one_step_predictions",
]
