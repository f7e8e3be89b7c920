"""Style-transfer losses besides FAST: ablation baselines, content and total variation, and a dispatcher.

All feature inputs are per matching group, ``(C, N)`` column matrices (rendered ``F_r`` with grad,
style ``F_s`` without, or the style side prepared once as :class:`abcgs.features.knn.StyleFeatures`); group
losses are summed, like FAST's.

- :func:`nnfm_loss` — ARF's nearest-neighbour feature matching: mean over rendered features of
  ``1 − max_j cos(F_r[:, i], F_s[:, j])`` (target gathered without grad).
- :func:`knnfm_loss` — mean cosine distance to the average of the k nearest style features.
- :func:`gram_loss` — Gatys: MSE between Gram matrices ``F Fᵀ / (C N)``.
- :func:`content_loss` — MSE over all feature elements (ARF/ABC-GS code's convention: mean over
  channels and pixels; the paper writes a sum over channels / pixels, which is C × this).
- :func:`tv_loss` — mean squared differences of horizontally and vertically adjacent pixels (ARF).
- :func:`structure_loss` — mean squared difference of the luminance gradients (Sobel) of the render and the content
  image: the fine structure (eyes, a mouth, lettering) that the content loss at relu3 sees only blurred.
- :func:`luminance_gradients` — the Sobel gradients of Rec. 601 luminance that :func:`structure_loss` compares.

The content and structure losses take an optional per-position weight map (``(h, w)`` / ``(H, W)``, the λ of each
position: a content label's own λ, :class:`abcgs.stylize.targets.LabelWeights`); without one they are plain means,
which the caller weights by a single λ.
- :func:`silhouette_loss`, :func:`background_loss` — an object scene's hold on its silhouette and its empty space
  (:mod:`abcgs.silhouette`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from abcgs.errors import InputError
from abcgs.features import knn
from abcgs.features.knn import Projection, StyleFeatures, as_style_features, check_feature_pair, cosine_topk
from abcgs.features.params import DEFAULT_MAX_BLOCK_ELEMS
from abcgs.losses.fast import FastStats, cosine_distance_loss, fast_loss
from abcgs.losses.params import FastParams
from abcgs.types import KnnSearch, StyleMethod

Groups = Sequence[tuple[torch.Tensor, "torch.Tensor | StyleFeatures"]]


def _check_groups(groups: Groups, what: str) -> None:
    if len(groups) == 0:
        raise InputError(f"{what}: no matching groups")
    for f_r, f_s in groups:
        check_feature_pair(f_r, f_s.raw if isinstance(f_s, StyleFeatures) else f_s, what)


def knn_average_target(
    f_r: torch.Tensor,
    f_s: torch.Tensor | StyleFeatures,
    k: int,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    search: KnnSearch = "exact",
    projection: Projection | None = None,
) -> torch.Tensor:
    """``(C, N_r)``: for each rendered feature, the mean of its k most cosine-similar style features (no grad).

    ``search``: :func:`abcgs.features.knn.cosine_topk`'s (``exact``, certified ``bf16`` or ``auto``; same neighbours);
    ``projection``: the approximate search instead.
    """
    style = as_style_features(f_s)
    nn_rs, _ = cosine_topk(f_r, style, k, 0, max_block_elems=max_block_elems, search=search, projection=projection)
    assert nn_rs is not None
    with torch.no_grad():
        return style.raw[:, nn_rs].mean(dim=2)  # (C, N_r, k) → (C, N_r)


def nnfm_loss(
    groups: Groups,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    search: KnnSearch = "exact",
    projection: Projection | None = None,
) -> torch.Tensor:
    """ARF's NNFM loss summed over groups (chunked nearest-neighbour search)."""
    return knnfm_loss(groups, 1, max_block_elems=max_block_elems, search=search, projection=projection, what="NNFM")


def knnfm_loss(
    groups: Groups,
    k: int = 5,
    *,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
    search: KnnSearch = "exact",
    projection: Projection | None = None,
    what: str = "KNNFM",
) -> torch.Tensor:
    """KNNFM loss summed over groups: cosine distance to the mean of the k nearest style features."""
    if k < 1:
        raise InputError(f"{what}: k must be >= 1, got {k}")
    _check_groups(groups, what)
    return torch.stack(
        [
            cosine_distance_loss(
                f_r, knn_average_target(f_r, f_s, k, max_block_elems=max_block_elems, search=search, projection=projection)
            )
            for f_r, f_s in groups
        ]
    ).sum()


def gram_matrix(f: torch.Tensor) -> torch.Tensor:
    """``(C, N)`` → normalised Gram ``F Fᵀ / (C N)`` ``(C, C)``."""
    c, n = f.shape
    return (f @ f.t()) / (c * n)


def gram_loss(groups: Groups) -> torch.Tensor:
    """Gatys' style loss summed over groups: ``mean((G(F_r) − G(F_s))²)``."""
    _check_groups(groups, "Gram")
    return torch.stack([((gram_matrix(f_r) - gram_matrix(as_style_features(f_s).raw)) ** 2).mean() for f_r, f_s in groups]).sum()


def _weighted_mean(sq: torch.Tensor, weight: torch.Tensor | None, what: str) -> torch.Tensor:
    """``mean(sq)``, or ``mean(weight · sq)`` with ``weight`` broadcast over the leading axes of ``sq`` (its last two
    axes are the positions ``weight`` ``(h, w)`` weights)."""
    if weight is None:
        return sq.mean()
    if weight.ndim != 2 or tuple(weight.shape) != tuple(sq.shape[-2:]):
        raise InputError(f"{what}: weight map {tuple(weight.shape)} does not match positions {tuple(sq.shape[-2:])}")
    return (sq * weight).mean()


def content_loss(f_render: torch.Tensor, f_content: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """MSE between rendered and content (pre-stylisation render) features of any equal shape, e.g. ``(C, h, w)``;
    with ``weight`` ``(h, w)``, each position's squared error times its weight (the mean over every element still)."""
    if f_render.shape != f_content.shape:
        raise InputError(f"content loss: feature shapes differ {tuple(f_render.shape)} vs {tuple(f_content.shape)}")
    return _weighted_mean((f_render - f_content.detach()) ** 2, weight, "content loss")


LUMA = (0.299, 0.587, 0.114)
"""Rec. 601 luminance weights of R, G, B."""


def luminance_gradients(img: torch.Tensor) -> torch.Tensor:
    """``(H, W, 3)`` RGB → ``(2, H, W)`` Sobel gradients ``(∂Y/∂x, ∂Y/∂y)`` of its Rec. 601 luminance ``Y``, each
    divided by 4 (a unit step of ``Y`` across a pixel edge gives 1), with replicated borders."""
    if img.ndim != 3 or img.shape[-1] != 3 or img.shape[0] < 2 or img.shape[1] < 2:
        raise InputError(f"luminance gradients expect an (H, W, 3) image with H, W >= 2; got {tuple(img.shape)}")
    y = (img * img.new_tensor(LUMA)).sum(-1)[None, None]
    k = img.new_tensor([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]]) / 4.0
    kernels = torch.stack([k, k.t()])[:, None]  # (2, 1, 3, 3): x then y
    return torch.nn.functional.conv2d(torch.nn.functional.pad(y, (1, 1, 1, 1), mode="replicate"), kernels)[0]


def structure_loss(img: torch.Tensor, content: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over pixels and both axes of ``(∇Y(img) − ∇Y(content))²`` (:func:`luminance_gradients`) between a render
    ``(H, W, 3)`` and the content image (the colour-matched render, no grad); ``weight`` ``(H, W)``: per pixel."""
    if img.shape != content.shape:
        raise InputError(f"structure loss: image shapes differ {tuple(img.shape)} vs {tuple(content.shape)}")
    with torch.no_grad():
        target = luminance_gradients(content)
    return _weighted_mean((luminance_gradients(img) - target) ** 2, weight, "structure loss")


def tv_loss(img: torch.Tensor) -> torch.Tensor:
    """Total variation of ``(B, C, H, W)``: ``mean(Δ_x²) + mean(Δ_y²)`` (ARF's ``get_tv_loss``)."""
    if img.ndim != 4 or img.shape[-1] < 2 or img.shape[-2] < 2:
        raise InputError(f"TV loss expects (B, C, H, W) with H, W >= 2; got {tuple(img.shape)}")
    dx = img[..., :, 1:] - img[..., :, :-1]
    dy = img[..., 1:, :] - img[..., :-1, :]
    return (dx**2).mean() + (dy**2).mean()


def style_loss(
    method: StyleMethod,
    groups: Groups,
    *,
    k: int = 5,
    fast_params: FastParams | None = None,
    stats: FastStats | None = None,
    max_block_elems: int = DEFAULT_MAX_BLOCK_ELEMS,
) -> torch.Tensor:
    """Style loss by name over matching groups ``[(F_r^z (C, N_r), F_s^z (C, N_s)), …]`` → scalar.

    ``fast``: ABC-GS's FAST (``fast_params``, default k=5, ε=1e-12; its ``k``/``max_block_elems`` win over
    the arguments here); ``nnfm``: ARF; ``knnfm``: k-NN average; ``gram``: Gatys. The neighbour searches
    of all three use ``fast_params.knn_search`` (default ``auto``: certified bf16 where it pays; the same
    neighbours as the exact search), or the approximate projected search where ``fast_params.projection_rank > 0``.
    """
    search = (fast_params or FastParams()).knn_search
    projection = knn.projection_of(fast_params or FastParams())
    if method == "fast":
        params = fast_params or FastParams(k=k, max_block_elems=max_block_elems)
        return fast_loss(groups, params, stats)
    if method == "nnfm":
        return nnfm_loss(groups, max_block_elems=max_block_elems, search=search, projection=projection)
    if method == "knnfm":
        return knnfm_loss(groups, k, max_block_elems=max_block_elems, search=search, projection=projection)
    if method == "gram":
        return gram_loss(groups)
    raise InputError(f"unknown style loss {method!r}; choose one of fast, nnfm, knnfm, gram")


def silhouette_loss(alpha: torch.Tensor, ref_alpha: torch.Tensor) -> torch.Tensor:
    """Mean ``|α − α_ref|`` over the pixels of a render's alpha ``(H, W, 1)`` and the original scene's: holds an
    object's silhouette (no Gaussian grows or spreads into empty space, none fades from the object)."""
    return (alpha - ref_alpha).abs().mean()


def background_loss(image: torch.Tensor, background: torch.Tensor, empty: torch.Tensor) -> torch.Tensor:
    """Mean ``|image − background|`` over the ``empty`` ``(H, W)`` pixels of a render ``(H, W, 3)`` composited on
    ``background`` ``(3,)``: what a faint Gaussian would add there (a brightened or recoloured haze) is penalised;
    0 when no pixel is empty."""
    if not bool(empty.any()):
        return image.sum() * 0.0
    return (image[empty] - background).abs().mean()
