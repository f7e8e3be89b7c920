"""The structure term, the content and structure λ per content label (an experiment's ``content_weights`` and
``structure_weights``): values, gradients against finite differences, the schema's refusals, and a label's λ changing
only its own region of a stylization."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from test_style_lifting import _two_blob_scene

from abcgs.cameras import Camera, intrinsics, look_at
from abcgs.errors import InputError
from abcgs.features.matching import build_groups
from abcgs.features.params import ExperimentParams, TransferSpec
from abcgs.features.vgg import VGG16Features, random_state_dict
from abcgs.gaussians import render
from abcgs.io.images import save_image
from abcgs.losses import terms as losses
from abcgs.masks.lifting import render_label_map
from abcgs.stylize.loop import stylize
from abcgs.stylize.params import StyleWeights, StylizeCompute, StylizeOptim, StylizeParams
from abcgs.stylize.targets import LabelWeights


def test_luminance_gradients_of_a_step_and_of_a_ramp() -> None:
    img = torch.zeros(6, 8, 3, dtype=torch.float64)
    img[:, 4:] = 1.0  # a unit step of luminance between columns 3 and 4
    g = losses.luminance_gradients(img)
    assert g.shape == (2, 6, 8)
    assert torch.allclose(g[0][:, 3:5], torch.ones(6, 2, dtype=torch.float64)) and float(g[0][:, :3].abs().max()) < 1e-12
    assert float(g[1].abs().max()) < 1e-12  # nothing changes down the columns
    ramp = torch.arange(8, dtype=torch.float64).repeat(6, 1)[..., None].expand(6, 8, 3) * 0.1
    assert torch.allclose(losses.luminance_gradients(ramp)[0][:, 1:-1], torch.full((6, 6), 0.2, dtype=torch.float64))
    red = torch.zeros(6, 8, 3, dtype=torch.float64)
    red[:, 4:, 0] = 1.0  # Rec. 601: a red step is 0.299 of a white one
    assert float(losses.luminance_gradients(red)[0].max()) == pytest.approx(0.299)


def test_structure_loss_values_and_weights() -> None:
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(5, 7, 3, generator=g), torch.rand(5, 7, 3, generator=g)
    assert float(losses.structure_loss(a, a)) == 0.0
    assert float(losses.structure_loss(a, b)) > 0.0
    assert float(losses.structure_loss(a, a + 0.3)) == pytest.approx(0.0, abs=1e-12)  # a brighter copy keeps its edges
    want = ((losses.luminance_gradients(a) - losses.luminance_gradients(b)) ** 2).mean()
    assert torch.allclose(losses.structure_loss(a, b), want)
    uniform = torch.full((5, 7), 3.0)
    assert torch.allclose(losses.structure_loss(a, b, uniform), 3.0 * want)
    left = torch.zeros(5, 7)
    left[:, :3] = 1.0
    sq = (losses.luminance_gradients(a) - losses.luminance_gradients(b)) ** 2
    assert torch.allclose(losses.structure_loss(a, b, left), (sq * left).mean())
    f_r, f_c = torch.rand(4, 5, 7, generator=g), torch.rand(4, 5, 7, generator=g)
    assert torch.allclose(losses.content_loss(f_r, f_c, uniform), 3.0 * losses.content_loss(f_r, f_c))
    with pytest.raises(InputError, match="weight map"):
        losses.content_loss(f_r, f_c, torch.ones(3, 3))
    with pytest.raises(InputError, match="shapes differ"):
        losses.structure_loss(a, b[:4])


def test_weighted_content_and_structure_gradcheck() -> None:
    g = torch.Generator().manual_seed(1)
    img = torch.rand(5, 6, 3, generator=g, dtype=torch.float64, requires_grad=True)
    ref = torch.rand(5, 6, 3, generator=g, dtype=torch.float64)
    w = torch.rand(5, 6, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: losses.structure_loss(t, ref, w), (img,))
    assert torch.autograd.gradcheck(lambda t: losses.structure_loss(t, ref), (img,))
    f = torch.rand(3, 5, 6, generator=g, dtype=torch.float64, requires_grad=True)
    fc = torch.rand(3, 5, 6, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: losses.content_loss(t, fc, w), (f,))


def test_label_weight_maps() -> None:
    lab = np.zeros((8, 8), np.int64)
    lab[:, 4:] = 2
    lab[:4, :4] = 1
    lw = LabelWeights(content={2: 1.0}, structure={1: 5.0})
    content = lw.pixel_map("content", 0.25, lab)
    assert content[0, 0] == 0.25 and content[0, 5] == 1.0
    assert LabelWeights().pixel_map("content", 0.25, lab) is None
    c, s = lw.maps({"content": 0.25, "structure": 0.0}, lab, (2, 2), torch.device("cpu"))
    assert c.tolist() == [[0.25, 1.0], [0.25, 1.0]]  # each cell the mean of its 4 x 4 pixels
    assert s.shape == (8, 8) and float(s[0, 0]) == 5.0 and float(s[6, 0]) == 0.0 and float(s[0, 6]) == 0.0
    c, s = LabelWeights(content={1: 1.0}).maps({"content": 0.0, "structure": 0.0}, lab, (4, 4), torch.device("cpu"))
    assert s is None and float(c[0, 0]) == 1.0 and float(c[3, 0]) == 0.0


@pytest.mark.parametrize("entry, match", [
    ({"content_weights": {0: 1.0}}, "label 0 is outside 1..254"),
    ({"structure_weights": {255: 1.0}}, "label 255 is outside 1..254"),
    ({"content_weights": {2: -1.0}}, r"content_weights.2 = -1.0 is outside \[0, 10000\]"),
    ({"content_weights": {2: float("nan")}}, r"content_weights.2 = nan is outside"),
    ({"structure_weights": {2: 1e6}}, r"structure_weights.2 = 1000000.0 is outside"),
])
def test_an_experiment_refuses_a_bad_label_weight(entry, match) -> None:
    with pytest.raises(ValidationError, match=match):
        ExperimentParams(scene="s", colormatch="c", **entry)
    ok = ExperimentParams(scene="s", colormatch="c", content_weights={2: 0.005}, structure_weights={1: 1.0})
    assert ok.label_weighted == {1, 2}


def two_blob_runner(folder):
    """The two-blob scene (label 1 left, 2 right) stylized compositionally, one painting per blob: a function of
    (seed, label weights) → the stylized renders, and the views' label maps."""
    model, truth = _two_blob_scene(3, separation=1.6, spread=0.25)
    K = intrinsics(40.0, 128, 96)
    cams = [Camera(f"{i:03d}.png", K, look_at(np.array([0.2 * (i - 1), 0.1 * i, 0.0]), np.array([0.0, 0.0, 4.0])),
                   128, 96) for i in range(3)]
    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        save_image(folder / f"{name}.png", rng.random((48, 64, 3)).astype(np.float32))
    vgg = VGG16Features(random_state_dict(0))
    styles = {n: str(folder / f"{n}.png") for n in ("a", "b")}
    groups = build_groups(TransferSpec(scene="s", transfer="compositional", styles={1: "a", 2: "b"}), styles, {},
                          {1, 2}, vgg, style_height=48)
    labels = [render_label_map(model, truth, 2, c) for c in cams]
    base = StylizeParams(optim=StylizeOptim(iterations=20, lr_sh0=0.05, color_pass_iterations=0),
                         compute=StylizeCompute(log_every=5), downsample_render=False,
                         weights=StyleWeights(depth=0.0, content=0.01, structure=0.0))

    def run(seed: int, lw: LabelWeights) -> list[np.ndarray]:
        params = base.model_copy(update={"seed": seed})
        res = stylize(model, cams, labels, truth, groups, vgg, params, progress=False, label_weights=lw)
        with torch.no_grad():
            return [render(res.model, c)[0].numpy() for c in cams]

    return run, labels


@pytest.fixture(scope="module")
def two_blob_run(tmp_path_factory):
    return two_blob_runner(tmp_path_factory.mktemp("paint"))


def test_a_label_weight_changes_only_its_own_region(two_blob_run) -> None:
    run, labels = two_blob_run
    base, other_seed = run(0, LabelWeights()), run(1, LabelWeights())
    held = run(0, LabelWeights(content={1: 50.0}, structure={1: 50.0}))

    def change(a, b, label):
        return float(np.mean([np.abs(x - y)[lab == label].mean() for x, y, lab in zip(a, b, labels)]))

    noise = change(base, other_seed, 2)
    assert change(held, base, 1) > 10 * change(held, base, 2)
    assert change(held, base, 2) <= max(noise, 1e-6), (change(held, base, 2), noise)
    assert change(held, base, 1) > noise  # the weight does something beyond what another seed does
