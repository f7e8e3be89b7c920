"""Paintings brought under out/ (the styles stages) read exactly as the files the params name."""

from __future__ import annotations

import numpy as np
import pytest

from abcgs.errors import InputError


@pytest.mark.parametrize("case", ["jpeg", "png16", "rgba", "grey"])
def test_copy_as_png_keeps_the_decoded_pixels(tmp_path, case) -> None:
    """A painting copied under out/styles reads exactly as the original does, whatever its format."""
    import cv2

    from abcgs.io.images import copy_as_png, load_image, load_labels

    rng = np.random.default_rng(0)
    img = {"jpeg": rng.integers(0, 256, (20, 30, 3), dtype=np.uint8),
           "png16": rng.integers(0, 65536, (20, 30, 3), dtype=np.uint16),
           "rgba": rng.integers(0, 256, (20, 30, 4), dtype=np.uint8),
           "grey": rng.integers(0, 8, (20, 30), dtype=np.uint8)}[case]
    src = tmp_path / ("p.jpg" if case == "jpeg" else "p.png")
    cv2.imwrite(str(src), img)
    assert copy_as_png(src, tmp_path / "copy.png") == (30, 20)
    np.testing.assert_array_equal(load_image(tmp_path / "copy.png"), load_image(src))
    if case == "grey":
        np.testing.assert_array_equal(load_labels(tmp_path / "copy.png"), load_labels(src))
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="bad.png"):
        copy_as_png(tmp_path / "bad.png", tmp_path / "x.png")
