"""Fuzzing every reader of files from other tools (eval/bench/fuzz.py): a few hundred seeded mutations per format —
truncated, bytes flipped, counts inflated, numbers replaced by NaN/inf/0/huge, records repeated, JSON nested — each
read as a scene or refused with a one-line InputError (the masks page: a 4xx Refused), none slower than SLOW_S.
The longer run is ``python -m eval run fuzz --inputs 10000`` (docs/measurements/fuzz.json)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from eval.bench.fuzz import FORMATS, SLOW_S, fuzz_target, make_targets
from eval.bench.fuzz_mutations import gzip_bomb

INPUTS = 150


@pytest.fixture(scope="module")
def targets(tmp_path_factory):
    return make_targets(Path(tmp_path_factory.mktemp("fuzz")))


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_mutated_input_is_read_or_refused_in_one_line(targets, fmt: str) -> None:
    logging.disable(logging.WARNING)
    try:
        run = fuzz_target(targets[fmt], INPUTS, seed=1)
    finally:
        logging.disable(logging.NOTSET)
    assert run.inputs == INPUTS and run.read + run.refused == INPUTS - len(run.findings)
    assert not run.findings, "\n".join(f"#{f.index} {f.mutation} {f.file}: {f.error}" for f in run.findings[:10])
    assert run.slowest_s < SLOW_S
    assert run.refused > INPUTS // 3  # the mutations do reach the checks


def test_the_bomb_builder_makes_a_stream_that_inflates_to_its_size() -> None:
    import zlib

    bomb = gzip_bomb(b"head", 3 << 20)
    assert len(bomb) < 20_000
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    assert len(d.decompress(bomb[:-8])) == 4 + (3 << 20)  # the trailer (CRC, size) is a bomb's own
