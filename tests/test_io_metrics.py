"""DVC metrics files keep numbers; the complete record goes to ``*_info.json`` (read back by read_record)."""

from __future__ import annotations

import json

from abcgs.io.metrics import info_path, numeric_leaves, read_record, write_metrics


def test_numeric_leaves_drop_strings_lists_none_and_nonfinite() -> None:
    rec = {"ssim": 0.5, "n": 3, "ok": True, "name": "fast", "res": [1, 2], "std": None, "bad": float("nan"),
           "speed": {"fps": 20.0, "backend": "cpu"}, "provenance": {"path": "/x", "sha": "ab"}}
    assert numeric_leaves(rec) == {"ssim": 0.5, "n": 3, "ok": True, "speed": {"fps": 20.0}}


def test_write_metrics_splits_and_read_record_prefers_the_info_file(tmp_path) -> None:
    rec = {"experiment": "e", "ssim": 0.25, "provenance": {"weights": {"sha256": "00ff"}}, "inf": float("inf")}
    path = tmp_path / "eval.json"
    info = write_metrics(path, rec)
    assert info == info_path(path) == tmp_path / "eval_info.json"
    assert json.loads(path.read_text()) == {"ssim": 0.25}
    full = json.loads(info.read_text())
    assert full["provenance"]["weights"]["sha256"] == "00ff" and full["inf"] is None  # JSON has no Infinity
    assert read_record(path) == full
    info.unlink()  # a run written before the split: the metrics file is the record
    assert read_record(path) == {"ssim": 0.25}
    assert not list(tmp_path.glob("*.tmp*"))
