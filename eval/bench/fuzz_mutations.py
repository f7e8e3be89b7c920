"""The mutations of the fuzzing suite (:mod:`eval.bench.fuzz`): each takes a valid input's bytes and a seeded
generator and returns them changed the way a broken or hostile tool would: truncated, bytes flipped, inserted or
overwritten with special values, a record repeated, a count or size field inflated, a number replaced, the JSON
nested deeply, a gzip stream padded to a bomb. :data:`MUTATIONS` says which each kind of input gets."""

from __future__ import annotations

import gzip
import json
import re
import struct
import zlib
from collections.abc import Callable

from abcgs.runtime import setup

setup()  # before torch loads: OpenMP's wait policy, OpenCV before pycolmap

# isort: split
import numpy as np

from eval.bench import fuzz_inputs

SPECIAL_NUMBERS = ("0", "-1", "NaN", "Infinity", "-Infinity", "1e400", "1e-300", "1e30", "99999999999999999999",
                   "3.5", '"x"', "[]", "{}", "null", "true", "²", "5" * 5000)
"""What a number in a text file is replaced by (JSON spellings; COLMAP's text reader sees them as tokens)."""
SPECIAL_BINARY = (b"\x00\x00\xc0\x7f", b"\x00\x00\x80\x7f", b"\x00\x00\x80\xff", b"\xff\xff\xff\xff", b"\x00" * 4,
                  b"\xff\xff\xff\x7f", struct.pack("<d", float("nan")), struct.pack("<d", float("inf")),
                  struct.pack("<Q", 1 << 40), struct.pack("<Q", (1 << 64) - 1), struct.pack("<d", 0.0))
"""Bytes written over a binary file: float32/float64 NaN and infinities, zero, and huge counts."""


def _truncate(data: bytes, rng: np.random.Generator) -> bytes:
    return data[: int(rng.integers(0, max(len(data), 1)))]


def _flip(data: bytes, rng: np.random.Generator) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        if b:
            b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
    return bytes(b)


def _insert(data: bytes, rng: np.random.Generator) -> bytes:
    at = int(rng.integers(0, len(data) + 1))
    return data[:at] + rng.bytes(int(rng.integers(1, 64))) + data[at:]


def _overwrite(data: bytes, rng: np.random.Generator) -> bytes:
    """A NaN, an infinity, a zero or a huge count written over the bytes at a random (4-aligned) place."""
    value = SPECIAL_BINARY[int(rng.integers(len(SPECIAL_BINARY)))]
    if len(data) < len(value):
        return value
    at = int(rng.integers(0, (len(data) - len(value)) // 4 + 1)) * 4
    return data[:at] + value + data[at + len(value):]


def _repeat(data: bytes, rng: np.random.Generator) -> bytes:
    """A span of the input repeated (a record twice, a longer body than its count)."""
    a = int(rng.integers(0, len(data) + 1))
    b = min(len(data), a + int(rng.integers(1, 256)))
    return data[:b] + data[a:b] * int(rng.integers(1, 4)) + data[b:]


def _number(data: bytes, rng: np.random.Generator) -> bytes:
    """One number of a text file replaced by a special value (:data:`SPECIAL_NUMBERS`)."""
    text = data.decode("utf-8", "replace")
    spots = [m.span() for m in re.finditer(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", text)]
    if not spots:
        return _flip(data, rng)
    a, b = spots[int(rng.integers(len(spots)))]
    return (text[:a] + SPECIAL_NUMBERS[int(rng.integers(len(SPECIAL_NUMBERS)))] + text[b:]).encode()


def _line(data: bytes, rng: np.random.Generator) -> bytes:
    """A line of a text file repeated or dropped."""
    lines = data.split(b"\n")
    i = int(rng.integers(len(lines)))
    if rng.random() < 0.5:
        lines.insert(i, lines[i])
    else:
        del lines[i]
    return b"\n".join(lines)


def _json_edit(data: bytes, rng: np.random.Generator) -> bytes:
    """A structural edit of a JSON document: a value replaced, a frame repeated, a key dropped, a value nested."""
    try:
        doc = json.loads(data)
    except (ValueError, RecursionError):
        return _flip(data, rng)
    nodes: list[tuple[object, object]] = []  # (container, key) of every value

    def walk(v, depth=0):
        if depth > 40:
            return
        items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
        for k, child in items:
            nodes.append((v, k))
            walk(child, depth + 1)
    walk(doc)
    if not nodes:
        return data
    container, key = nodes[int(rng.integers(len(nodes)))]
    op = int(rng.integers(5))
    if op == 0:
        special = SPECIAL_NUMBERS[int(rng.integers(len(SPECIAL_NUMBERS)))]
        container[key] = (10**4000 if len(special) > 100 else "²" if special == "²" else
                          json.loads(special.replace("NaN", '"NaN"').replace("-Infinity", "-1e999").replace(
                              "Infinity", "1e999")))
    elif op == 1 and isinstance(container, list):
        container.insert(int(key), json.loads(json.dumps(container[key])))
    elif op == 1 and isinstance(container, dict) and isinstance(container.get("frames"), list):
        container["frames"] = container["frames"] * int(rng.integers(2, 50))
    elif op == 2:
        del container[key]
    elif op == 3:
        container[key] = [container[key]]
    else:
        container[key] = "../" * int(rng.integers(1, 4)) + "elsewhere.png" if isinstance(container[key], str) else -1
    return json.dumps(doc).encode()


def _nest(data: bytes, rng: np.random.Generator) -> bytes:
    """The document nested in ``depth`` lists (up to 200 000)."""
    depth = int(rng.choice([100, 1000, 5000, 200_000]))
    at = data.find(b"[") if rng.random() < 0.5 else -1
    if at < 0:
        return b"[" * depth + data + b"]" * depth
    return data[:at] + b"[" * depth + data[at:] + b"]" * depth


def _header_count(data: bytes, rng: np.random.Generator) -> bytes:
    """A count in a header inflated (a PLY's ``element vertex N``, a binary model's leading count)."""
    huge = int(rng.choice([0, 1, 1 << 31, 1 << 40, 10**18]))
    m = re.search(rb"element vertex (\d+)", data[:2000])
    if m:
        return data[: m.start(1)] + str(huge).encode() + data[m.end(1):]
    return struct.pack("<Q", huge % (1 << 64)) + data[8:]


def _spz_count(data: bytes, rng: np.random.Generator) -> bytes:
    """The Gaussian count of an (inflated) spz header replaced."""
    huge = int(rng.choice([0, 1, 1 << 20, 1 << 31, (1 << 32) - 1]))
    return data[:8] + struct.pack("<I", huge) + data[12:]


def _inflated(mutate: Callable[[bytes, np.random.Generator], bytes]):
    """A mutation of a gzip stream's content (the stream re-compressed), so that it reaches past the gzip checks."""
    def go(data: bytes, rng: np.random.Generator) -> bytes:
        return gzip.compress(mutate(gzip.decompress(data), rng), mtime=0)
    go.__name__ = f"inflated{mutate.__name__}"
    return go


def _bomb(data: bytes, rng: np.random.Generator) -> bytes:
    """The content followed by up to 4 GiB of zeros in a few MB of deflate (repeated flushed blocks)."""
    return gzip_bomb(gzip.decompress(data), int(rng.choice([1 << 20, 1 << 28, 1 << 32])))


def gzip_bomb(head: bytes, zeros: int) -> bytes:
    """A gzip stream of ``head`` then ``zeros`` zero bytes, built in milliseconds: one compressed, byte-aligned
    block of 1 MiB of zeros is repeated (the CRC is wrong, as a hostile file's may be; a reader stops long before)."""
    comp = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
    out = comp.compress(head) + comp.flush(zlib.Z_FULL_FLUSH)
    block = zlib.compressobj(9, zlib.DEFLATED, -zlib.MAX_WBITS)
    chunk = block.compress(b"\0" * (1 << 20)) + block.flush(zlib.Z_FULL_FLUSH)
    return out + chunk * max(1, zeros >> 20) + b"\x03\x00" + struct.pack("<II", 0, (len(head) + zeros) & 0xFFFFFFFF)


MUTATIONS: dict[str, tuple[Callable[[bytes, np.random.Generator], bytes], ...]] = {
    "bytes": (_truncate, _flip, _insert, _overwrite, _repeat, _header_count),
    "npy": (_truncate, _flip, _insert, _overwrite, _repeat),
    "gzip": (_truncate, _flip, _insert, _inflated(_flip), _inflated(_overwrite), _inflated(_truncate),
             _inflated(_spz_count), _inflated(_repeat), _bomb),
    "text": (_truncate, _flip, _insert, _number, _line, _repeat),
    "json": (_truncate, _flip, _insert, _number, _json_edit, _json_edit, _nest),
    "png": (_truncate, _flip, _insert, _overwrite, *fuzz_inputs.OWN_MUTATIONS["png"] * 3),
    "ckpt": (_truncate, _flip, _insert, *fuzz_inputs.OWN_MUTATIONS["ckpt"] * 4),
    "yaml": (_truncate, _flip, _insert, _number, _line, _nest, *fuzz_inputs.OWN_MUTATIONS["yaml"] * 2),
    "special": (),
}
"""The mutations each kind of input gets, drawn uniformly."""
