"""The table scripts' publishing (scripts/table_sweep.py): an experiment run with `--no-doc`,
often on a subset of the matrix, must not overwrite the published figures."""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "scripts"))
import table_sweep


@pytest.fixture
def published(tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch) -> tuple[pathlib.Path, list[str]]:
    """A repository root in `tmp_path` whose docs/pipeline/robustness.json holds the full
    matrix, and the blocks written to docs/results/ (recorded, not written)."""
    (tmp_path / "docs" / "pipeline").mkdir(parents=True)
    (tmp_path / "docs" / "pipeline" / "robustness.json").write_text(json.dumps({"runs": ["stereo", "vio"]}))
    blocks: list[str] = []
    monkeypatch.setattr(table_sweep, "ROOT", tmp_path)
    monkeypatch.setattr(table_sweep, "write_block", lambda block, body: blocks.append(block))
    return tmp_path / "docs" / "pipeline" / "robustness.json", blocks


def test_no_doc_leaves_the_published_json_and_page(published: tuple[pathlib.Path, list[str]], capsys: pytest.CaptureFixture[str]) -> None:
    path, blocks = published
    table_sweep.publish({"runs": ["vio"]}, "| table |", json_name="robustness.json", block="robustness-table", write_doc=False)
    assert json.loads(path.read_text()) == {"runs": ["stereo", "vio"]}
    assert blocks == []
    assert "| table |" in capsys.readouterr().out


def test_publishing_writes_the_json_and_the_page(published: tuple[pathlib.Path, list[str]]) -> None:
    path, blocks = published
    table_sweep.publish({"runs": ["vio"]}, "| table |", json_name="robustness.json", block="robustness-table", write_doc=True)
    assert json.loads(path.read_text()) == {"runs": ["vio"]}
    assert blocks == ["robustness-table"]
