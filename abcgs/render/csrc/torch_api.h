// The part of torch the kernels use: ATen's tensors and operators, and pybind11 with torch's tensor casters for the
// module's functions. <torch/extension.h> would also bring the C++ frontend (autograd, nn, optim), twice the parse time
// of the unit for nothing it calls.
#pragma once
#include <ATen/ATen.h>
#include <torch/csrc/utils/pybind.h>
