"""Parameter files that no run could work with, refused before a bag is read (forty-seventh session)."""

from __future__ import annotations

import pytest

from okid_ros.errors import ParameterError
from okid_ros.tools.node_parameters import load_node_parameters

SOURCES = "    inputs:\n      sources: ['io_sample /okid/io_sample {}']\n"
NODE_2_SECTIONS = {
    "sample_time_s": "    sample_time_s: 0.004\n",
    "n_inputs": "    n_inputs: 0\n" + SOURCES.format("y[0]=y0 y[1]=y1"),
    "n_outputs": "    n_outputs: 1\n" + SOURCES.format("u[0]=u0 u[1]=u1 y[0]=y0"),
}


@pytest.mark.parametrize("name", sorted(NODE_2_SECTIONS))
def test_a_size_set_for_node_2_alone_is_refused(tmp_path, name):
    """Node 2 refuses every ArxModel of another sample time or size: `process` ran the whole bag for no model."""
    path = tmp_path / "split.yaml"
    path.write_text("/**/okid_modal_estimator:\n  ros__parameters:\n" + NODE_2_SECTIONS[name])
    with pytest.raises(ParameterError) as caught:
        load_node_parameters([path])
    text = str(caught.value)
    assert text.startswith(f"parameter {name} differs between the nodes: okid_arx_identifier ")
    assert f"okid_modal_estimator {'0.004' if name == 'sample_time_s' else ''}" in text
    assert str(path) in text and "'/**' section" in text


def test_sizes_set_for_both_nodes_are_taken(tmp_path):
    """The same values in both nodes' sections (or one '/**' section) are no disagreement."""
    path = tmp_path / "both.yaml"
    path.write_text("/**/okid_modal_estimator:\n  ros__parameters:\n    sample_time_s: 0.004\n"
                    "/**/okid_arx_identifier:\n  ros__parameters:\n    sample_time_s: 0.004\n")
    arx, est = load_node_parameters([path])
    assert arx["sample_time_s"] == est["sample_time_s"] == 0.004
