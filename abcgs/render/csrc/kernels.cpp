// The C++ kernels as one translation unit: setup.py compiles this file once per build variant. Most of a kernel
// file's compile time is parsing <torch/extension.h>, so one unit instead of four parses it once per variant
// (docs/measurements/first_run.json: the install's time with this build).
#include "image_loss_cpu.cpp"
#include "knn_cpu.cpp"
#include "projection_cpu.cpp"
#include "rasterize_cpu.cpp"
#include "frozen_cpu.cpp"
#include "sh_cpu.cpp"
#include "batch_cpu.cpp"
#include "drift_cpu.cpp"
