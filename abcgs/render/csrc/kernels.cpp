// The C++ kernels as one translation unit: setup.py compiles this file once per build variant. A large part of a
// kernel file's compile time is parsing torch's headers (torch_api.h: 11 s of ATen and pybind11, where
// <torch/extension.h> took 22 s), so one unit parses them once per variant.
#include "image_loss_cpu.cpp"
#include "knn_cpu.cpp"
#include "projection_cpu.cpp"
#include "rasterize_cpu.cpp"
#include "frozen_cpu.cpp"
#include "sh_cpu.cpp"
#include "batch_cpu.cpp"
#include "drift_cpu.cpp"
