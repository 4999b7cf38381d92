"""Simulators with known truth: the records of ``okid-ros simulate`` and the demo.

The paper's published model and modal structures with process and measurement noise. What only
the benchmarks and tests use (the oracle predictor, named cases, scoring, switching systems,
peers) lives in ``bench/okid_bench``.

One role per module, imported in one direction (no cycle):

    models       system types (``InnovationModel`` of the core, ``NoisyStateSpace``), modal structures
    inputs       white and low-passed input sequences
    simulators   simulation of either kind of true system
    paper_model  the model published by Chen, Huang & Juang (1991)

No rclpy.  Time along axis 0 (``u`` is (N, m), ``y`` is (N, p)); innovation form in the paper's
convention ``x_{k+1} = A x_k + B u_k + A K e_k``, ``y_k = C x_k + D u_k + e_k``.
"""

from okid_ros.sim.inputs import lowpass_input, white_input
from okid_ros.sim.models import InnovationModel, NoisyStateSpace, modal_structure
from okid_ros.sim.paper_model import paper_model, paper_modes
from okid_ros.sim.simulators import propagate_states, simulate, simulate_innovation, simulate_noisy

__all__ = [
    "InnovationModel", "NoisyStateSpace", "lowpass_input", "modal_structure", "propagate_states", "simulate",
    "simulate_innovation", "simulate_noisy", "white_input", "paper_model", "paper_modes",
]
