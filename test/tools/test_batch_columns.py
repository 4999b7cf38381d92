"""The NaN of `okid-ros batch`'s modes.parquet: each column that may hold one says why in docs/batch.md.

`emac` was NaN on the updates whose model had more states than half the ARX order (the EMAC's
reference, the late half of the ARX's q system Markov parameters, has fewer terms than the model
has poles: the residues are not determined), and docs/batch.md listed it among no NaN columns.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from batch_helpers import batch, table_rows, write_good_bag, write_params
from ros_helpers import REPO_ROOT


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    return write_good_bag(tmp_path_factory.mktemp("columns") / "bag", 0)  # ARX order 20 by write_params


@pytest.mark.parametrize("n_states, emac_nan", [(12, True), (10, False)])
def test_emac_is_nan_exactly_when_the_model_has_more_states_than_half_the_arx_order(bag, tmp_path, n_states,
                                                                                    emac_nan):
    out = tmp_path / "campaign"
    assert batch(bag, "--out", out, "--params", write_params(tmp_path / "p.yaml"), "--param",
                 f"realization.n_states={n_states}") == 0
    rows = table_rows(out)
    assert rows and all(row["n_states"] == n_states for row in rows)
    assert all((row["emac"] is None) == emac_nan for row in rows), rows


def _column_notes() -> dict[str, str]:
    """docs/batch.md's modes.parquet columns -> the note in parentheses after each ("" if none)."""
    text = (REPO_ROOT / "docs" / "batch.md").read_text()
    paragraph = text[text.index("`modes.parquet` columns"):].split("\n\n")[0]
    body = paragraph.split(":", 1)[1]
    notes: dict[str, str] = {}
    for match in re.finditer(r"`(\w+)`(?:\s*\(((?:[^()]|\([^()]*\))*)\))?", body):
        notes[match.group(1)] = match.group(2) or ""
    return notes


def test_docs_say_why_emac_may_be_nan():
    notes = _column_notes()
    assert "emac" in notes and "NaN" in notes["emac"], notes.get("emac")
    assert "states" in notes["emac"] and "ARX order" in notes["emac"], notes["emac"]
