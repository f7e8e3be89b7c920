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


def test_headlines_keep_the_computed_names_and_only_headline_numbers(tmp_path) -> None:
    from abcgs.io.metrics import EXPERIMENT_HEADLINE, experiment_headline, fit_headline, write_headline

    ev = {"ssim": 0.5, "short_rmse": 0.06, "long_rmse": 0.09, "short_lpips_proxy_vgg": 0.7, "long_lpips_proxy_vgg": 1.1,
          "short_rmse_floor": 0.04, "long_rmse_floor": 0.05, "gram_distance": 0.3, "kid_tf_inception": 0.2, "kid_tf_inception_std": 0.01, "artfid_proxy": 900.0,
          "artfid_components": {"content_distance": {"value": 3.0}}, "stylize_minutes": 5.0, "n_views": 16,
          "short_valid_fraction": 0.8, "speed": {"render_fps": 20.0}, "fid_tf_inception": float("nan")}
    head = experiment_headline(ev)
    assert head == {"content_ssim": 0.5, "short_rmse": 0.06, "long_rmse": 0.09, "short_rmse_floor": 0.04,
                    "long_rmse_floor": 0.05, "short_lpips_proxy_vgg": 0.7, "long_lpips_proxy_vgg": 1.1, "gram_distance": 0.3, "kid_tf_inception": 0.2, "artfid_proxy": 900.0,
                    "stylize_minutes": 5.0}
    assert len(head) == len(EXPERIMENT_HEADLINE)
    # the official name only when the official metric was computed
    assert "short_lpips" in experiment_headline({"short_lpips": 0.1, "short_lpips_proxy_vgg": 0.7})
    assert "lpips" not in "".join(experiment_headline({"ssim": 1.0}))
    fit = fit_headline({"psnr": 25.0, "ssim": 0.9, "n_gaussians": 1000, "seconds": 120.0, "per_view": {"a": {"psnr": 1}}})
    assert fit == {"heldout_psnr": 25.0, "heldout_ssim": 0.9, "n_gaussians": 1000, "fit_minutes": 2.0}
    assert not set(fit) & set(head), "a fit headline name is also an experiment headline name"
    assert fit_headline({"psnr": None, "ssim": None, "n_gaussians": 5, "seconds": 60.0}) == {"n_gaussians": 5,
                                                                                             "fit_minutes": 1.0}
    p = write_headline(tmp_path / "m.json", {**fit, "note": "dropped"})
    assert json.loads(p.read_text()) == fit

