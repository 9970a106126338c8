"""``stats.json`` updates: merged with what is there, no temporary left, errors naming the file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdfrig.errors import StoreError
from brdfrig.session.stats import read_stats, update_stats


def test_update_adds_entries_and_keeps_the_rest(tmp_path):
    (tmp_path / "stats.json").write_text(json.dumps({"samples": {"a": {"model": "lobe"}}, "merged": 4}))
    update_stats(tmp_path, {"demo": {"error": np.float64(0.0123), "rows": np.array([1, 2])}})
    doc = read_stats(tmp_path)
    assert doc == {"samples": {"a": {"model": "lobe"}}, "merged": 4, "demo": {"error": 0.0123, "rows": [1, 2]}}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stats.json"]  # no temporary left


def test_errors_name_the_file(tmp_path):
    with pytest.raises(StoreError, match=r"stats\.json: no such file"):
        update_stats(tmp_path, {"x": 1})
    (tmp_path / "stats.json").write_text('{"merged": 4}')
    update_stats(tmp_path, {"x": float("nan")})  # not a JSON number: stored as its text (brdffile.jsonable)
    assert read_stats(tmp_path) == {"merged": 4, "x": "nan"}
    (tmp_path / "stats.json").write_text("[1, 2")
    with pytest.raises(StoreError, match=r"stats\.json: corrupt JSON"):
        read_stats(tmp_path)
