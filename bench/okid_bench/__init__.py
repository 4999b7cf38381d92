"""Simulated benchmark cases, peers and scoring: used by ``bench/`` and ``test/``, not installed.

The product's simulators (``okid_ros.sim``: models, inputs, simulators, the paper's model) make
records for ``okid-ros simulate`` and the demo; what only the benchmarks and tests need lives
here, one role per module:

    oracle     the oracle Kalman predictor of a true system and its one-step predictions
    cases      the named benchmark cases (true system, input, lengths)
    scoring    scores of an identified model against the truth (held-out prediction, modes)
    switching  piecewise-constant systems (a structural change mid-record) and their simulation
    changes    the change-detection scenarios built on them
    peers      other identification methods (SIPPY, nfoursid, python-control) behind one call
    output_only_cases  ambient records with discrete modal truth, and their scoring (output-only)

``bench/`` scripts import it as ``okid_bench`` (Python puts the script's folder on ``sys.path``);
the tests through ``pythonpath = bench`` in ``setup.cfg``.
"""
