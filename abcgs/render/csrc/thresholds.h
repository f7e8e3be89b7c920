// The alpha below which a Gaussian adds nothing to a pixel (1/255, the INRIA rasterizer's): the projection's
// opacity-aware radius (projection_cpu.cpp) and the rasterizer's blend (rasterize_cpu.cpp) share it.
#pragma once

constexpr double kAlphaThreshold = 1.0 / 255.0;
