"""DVC reads YAML with ruamel.yaml's C loader (the ruamel.yaml.clib dependency), and eval/bench/dvc_overhead.py's
timing of a dvc.lock's reads and rewrite."""

from __future__ import annotations

import yaml


def test_dvc_reads_yaml_with_the_c_loader() -> None:
    """dvc.utils.serialize.parse_yaml builds ``YAML(typ="safe")``: its parser is the C one where ruamel.yaml.clib is
    installed (ruamel.yaml 0.19 no longer installs it itself)."""
    from dvc.utils.serialize import parse_yaml
    from ruamel.yaml import YAML
    from ruamel.yaml.main import CParser

    assert CParser is not None, "ruamel.yaml.clib is missing: DVC reads dvc.lock in pure Python (pip install -e .)"
    assert YAML(typ="safe").Parser is CParser
    assert parse_yaml("stages:\n  a:\n    cmd: x\n", "dvc.lock") == {"stages": {"a": {"cmd": "x"}}}


def test_the_lock_timings_cover_each_way_dvc_reads_and_writes_it() -> None:
    from eval.bench.dvc_overhead import lock_parse_seconds

    lock = {"schema": "2.0", "stages": {f"s{i}": {"cmd": "python x.py", "deps": [
        {"path": f"abcgs/m{j}.py", "hash": "md5", "md5": "0" * 32, "size": j} for j in range(40)]} for i in range(20)}}
    seconds = lock_parse_seconds(yaml.safe_dump(lock), repeats=1)
    assert set(seconds) == {"safe_c", "safe_pure", "round_trip_load", "round_trip_dump"}
    assert all(v is not None and v > 0 for v in seconds.values()), seconds
    # which loader is faster is the benchmark's figure (docs/measurements/dvc_overhead.json), not asserted here: one
    # timing of each under the test suite's other lane can come out either way
